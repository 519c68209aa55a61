"""A run fitted to a time limit (train/time_limit.py): the stages shortened in the config's
proportions, stable as the run goes, ending by the limit; `train --minutes` end to end."""

import json
import time

import pytest
from training_subject import write_config

from archhead_addon.train.__main__ import main
from archhead_addon.train.run_folder import RunFolder
from archhead_addon.train.time_limit import fitted_steps, predicted_rates

PLANNED = (1000, 3000, 200, 800)
RATES = {1: 0.10, 2: 0.06, 3: 0.05, 4: 0.03}  # seconds a step


def stage_of(step: int, steps: tuple) -> int:
    end = 0
    for stage, n in enumerate(steps, start=1):
        end += n
        if step < end:
            return stage
    raise AssertionError("past the last step")


def simulate(seconds: float, rates=RATES, fit_rates=RATES) -> tuple[tuple, float]:
    """Steps taken at `rates`, refitted after each from the 5th with `fit_rates`: the final
    steps and the time they took."""
    current, step, clock = PLANNED, 0, 0.0
    while step < sum(current):
        clock += rates[stage_of(step, current)]
        step += 1
        if step >= 5:
            current = fitted_steps(current, PLANNED, step, fit_rates, seconds - clock)
    return current, clock


def test_enough_time_keeps_the_config_s_steps():
    need = sum(n * RATES[k] for k, n in enumerate(PLANNED, start=1))
    assert fitted_steps(PLANNED, PLANNED, 0, RATES, need + 1) == PLANNED
    assert simulate(need + 10) == (PLANNED, pytest.approx(need))


def test_the_stages_shrink_in_one_proportion_and_end_by_the_limit():
    """60 s for a plan of 314 s: every stage at 0.191 of its steps, from the first fit to the
    last (the fitted ends do not walk with the steps), the time used up to one step."""
    factor = 60 / sum(n * RATES[k] for k, n in enumerate(PLANNED, start=1))
    first = fitted_steps(PLANNED, PLANNED, 5, RATES, 60 - 5 * RATES[1])
    assert first == tuple(round(factor * n) for n in PLANNED)
    final, clock = simulate(60)
    assert all(abs(a - b) <= 1 for a, b in zip(final, first, strict=True))
    assert clock == pytest.approx(60, abs=0.1)


def test_a_slower_machine_than_predicted_still_ends_by_the_limit():
    """The fits predict 0.6x the real step times: the stages run long at first, the later
    ones give up the difference, and the run ends by the limit."""
    slow = {k: r / 0.6 for k, r in RATES.items()}
    final, clock = simulate(60, rates=slow, fit_rates=RATES)
    assert clock <= 60 + max(slow.values())
    assert all(0 < n <= p for n, p in zip(final, PLANNED, strict=True))


def test_a_stage_past_its_share_ends_and_every_stage_keeps_a_step():
    # 600 steps of stage 1 done, with time for little more: stage 1 ends where it is
    steps = fitted_steps(PLANNED, PLANNED, 600, RATES, 10.0)
    assert steps[0] == 600 and steps[1:] < PLANNED[1:]
    assert sum(n * RATES[k] for k, n in enumerate(steps[1:], start=2)) == pytest.approx(10, abs=0.1)
    # no time left: what stage 1 ran, one step of each later stage
    assert fitted_steps(PLANNED, PLANNED, 600, RATES, -5.0) == (600, 1, 1, 1)
    # a stage the config leaves out stays out; a finished stage keeps its steps
    assert fitted_steps((100, 0, 0, 50), (100, 0, 0, 50), 100, RATES, 0.0) == (100, 0, 0, 1)
    assert fitted_steps((300, 900, 60, 240), PLANNED, 400, RATES, 1e9)[0] == 300


def test_unmeasured_stages_are_predicted_from_the_nearest_measured_one():
    rates = predicted_rates({1: 0.1, 2: None, 3: None, 4: None}, 0.8)
    assert rates[2] == pytest.approx(0.08) and rates[3] < rates[2] and rates[4] < rates[3]
    resumed = predicted_rates({1: None, 2: None, 3: 0.05, 4: None}, 0.8)
    assert resumed[3] == 0.05 and resumed[4] < 0.05 and resumed[1] > resumed[2] > 0.05
    assert predicted_rates(dict.fromkeys((1, 2, 3, 4)), 0.8) == dict.fromkeys((1, 2, 3, 4))


def test_cli_ends_by_its_minutes_with_the_steps_it_took(tiny_subject, tmp_path, capsys):
    """A config of 100,000 steps with --minutes 0.25: the run stops by the limit (a generous
    margin: this is not a timing), shortened in every stage, its files agreeing (exit 0),
    config.json saying the limit and the steps taken, the last step's progress event the
    last of the steps as fitted; a negative limit is refused."""
    steps = {"stage1_steps": 40_000, "stage2_steps": 60_000, "checkpoint_every": 50}
    config = str(write_config(tmp_path / "tiny.json", **steps))
    out = tmp_path / "run"
    args = ["--data", str(tiny_subject), "--out", str(out), "--config", config]
    started = time.monotonic()
    assert main([*args, "--minutes", "0.25", "--progress-json"]) == 0
    assert time.monotonic() - started < 15 + 60
    saved = json.loads(RunFolder(out).config.read_text())
    manifest = json.loads(RunFolder(out).manifest.read_text())
    assert saved["minutes"] == 0.25
    taken = (saved["stage1_steps"], saved["stage2_steps"])
    assert 0 < taken[0] < 40_000 and 0 < taken[1] < 60_000
    assert manifest["step"] == manifest["total_steps"] == sum(taken)
    said = capsys.readouterr()
    assert "time limit:" in said.err
    steps = [e for e in map(json.loads, said.out.splitlines()) if e["event"] == "step"]
    assert steps[-1]["step"] == steps[-1]["total"] == sum(taken)
    assert main([*args[:3], str(tmp_path / "r2"), *args[4:], "--minutes", "-1"]) == 2
    assert "minutes" in capsys.readouterr().err
