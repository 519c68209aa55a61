"""A run fitted to a time limit (`train --minutes M`, the config's `minutes`; `avatar
--minutes M` gives training what tracking left): the stages' steps shortened in one
proportion so that the run, its checkpoints included, ends by the limit.

The config's steps are the most a run takes: a limit shortens and never lengthens. Once a
stage has run FIT_AFTER steps in this process (its mean step time then known), the steps are
fitted after each of its steps: the running stage and every later one take the config's
steps times one factor at most 1, the largest whose steps left fit the time left as
predicted. A stage that has not run yet is predicted from the ones before it
(`predicted_rates`); the fits correct the predictions as the stages come, and the last stage
takes up what they missed. The schedule follows the fitted lengths (each stage's
learning rates still decay to `lr_final_ratio` by its end); so a run with a limit does not
repeat step for step, as one without does. A resumed run keeps the steps its checkpoint
fitted, unless given a limit of its own (train/__main__.py), counted from its own start.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field

WARM_UP = 5  # a stage's first steps here, not timed: they build tables and caches
FIT_AFTER = 20  # steps of a stage run here before the steps are fitted
# A stage's step time is the mean of its latest steps: its first epoch costs more (each
# frame's pose computed once: a `cpu` stage-1 step 150 ms at first, 114 ms after).
RECENT = 200
# A step of stage 3 / 4 against a stage-2 one: the Pexels clip's time-limited `cpu` runs on
# the 2-core machine (stage 3 0.90-1.08 since the kernel's operations, 0.78-0.85 before;
# stage 4 0.42-0.50: docs/training.md); the refits correct them.
LATER_STAGE_COST = {3: 0.94, 4: 0.46}


def predicted_rates(rates: dict, stage2_ratio: float) -> dict:
    """Seconds a step by stage (1-4): those measured (`rates`, None where a stage has not
    run here), the others predicted from the nearest measured one (an earlier one first) by
    the stages' relative costs: stage 2 `stage2_ratio` times stage 1 (loop.stage2_cost_ratio),
    stages 3 and 4 LATER_STAGE_COST times stage 2. All None when none was measured."""
    cost = {1: 1.0, 2: stage2_ratio}
    cost.update({k: stage2_ratio * c for k, c in LATER_STAGE_COST.items()})
    measured = [k for k in cost if rates.get(k) is not None]
    out = {}
    for k in cost:
        if rates.get(k) is not None:
            out[k] = rates[k]
        elif measured:
            j = max((m for m in measured if m < k), default=min(measured))
            out[k] = rates[j] * cost[k] / cost[j]
        else:
            out[k] = None
    return out


def fitted_steps(
    current: tuple[int, ...], planned: tuple[int, ...], done: int, rates: dict, seconds: float
) -> tuple[int, ...]:
    """The stages' steps, `current` now and at most `planned`, after `done` steps (counted
    in `current`'s stages), so that the steps left take `seconds` at `rates` (seconds a
    step by stage, every stage with steps left included). The stages finished keep their
    steps; the one running and those after it take `planned` times one factor at most 1,
    the steps a stage has run counted in (a stage past its share ends where it is, and the
    others share the time left). A stage keeps at least one step."""
    stages = range(len(current))
    starts = [sum(current[:k]) for k in stages]
    ran = [min(max(done - starts[k], 0), current[k]) for k in stages]
    fixed = {k: current[k] for k in stages if not planned[k] or done >= starts[k] + current[k]}
    while True:
        free = [k for k in stages if k not in fixed]
        cost = sum(planned[k] * rates[k + 1] for k in free)
        credit = sum(ran[k] * rates[k + 1] for k in free)
        factor = min(1.0, max(seconds + credit, 0.0) / cost) if cost > 0 else 1.0
        past = [k for k in free if factor * planned[k] < ran[k]]
        if not past:
            break
        fixed.update({k: ran[k] for k in past})
    steps = [fixed.get(k, max(round(factor * planned[k]), ran[k])) for k in stages]
    return tuple(max(n, 1) if planned[k] else 0 for k, n in enumerate(steps))


@dataclass
class TimeLimit:
    """A run's limit: `deadline` (time.monotonic()) and the config's steps when it was set
    (`planned`, the most each stage takes)."""

    deadline: float
    planned: tuple[int, ...]
    save_seconds: float = 0.0  # the last checkpoint's writing time
    timed: dict = field(default_factory=dict)  # stage: its latest step times in this process
    steps_run: dict = field(default_factory=dict)  # stage: steps run in this process
    announced: set = field(default_factory=set)  # stages whose first fit was said

    @classmethod
    def minutes_from(cls, start: float, minutes: float, planned: tuple[int, ...]) -> TimeLimit:
        return cls(start + 60.0 * minutes, tuple(planned))

    def observe(self, stage: int, seconds: float) -> bool:
        """One more step of `stage` took `seconds`; whether to fit now: after every step
        from the stage's FIT_AFTER-th here (a fit costs nothing, and the stage's step time,
        its first WARM_UP steps left out, steadies as it goes)."""
        n = self.steps_run[stage] = self.steps_run.get(stage, 0) + 1
        if n > WARM_UP:
            self.timed.setdefault(stage, deque(maxlen=RECENT)).append(seconds)
        return n >= FIT_AFTER

    def rates(self) -> dict:
        """Seconds a step of each stage timed here, the mean of its RECENT latest (None:
        not timed)."""
        return {
            k: sum(self.timed[k]) / len(self.timed[k]) if k in self.timed else None
            for k in (1, 2, 3, 4)
        }

    def fit(self, current: tuple[int, ...], done: int, rates: dict, every: int) -> tuple[int, ...]:
        """The steps that end the run by the deadline (`fitted_steps`), each step charged its
        share of the checkpoints to come (one every `every` steps, and the last)."""
        per_step = self.save_seconds / every
        charged = {k: None if r is None else r + per_step for k, r in rates.items()}
        seconds = self.deadline - time.monotonic() - self.save_seconds
        return fitted_steps(current, self.planned, done, charged, seconds)
