"""A scene's Gaussian budget: the levels of detail of all its avatars, raised together until
the Gaussians they show fit (`Scene.archhead_crowd.gaussian_budget`).

Each avatar asks for its own level (slider, keys, distance driver). When their Gaussians
would pass the budget, one common amount b >= 0 is added to every level (each clamped to 1)
with b the smallest that fits: far heads, already coarse, reach LOD 1 first, and the near
ones keep what detail the budget allows. A level's count is its texels, which grow as the
UV area (S^2) plus the charts' edges (S): n(S) = a S^2 + b S through the counts at S_max and
S_min, exact there (the demo avatar's texels at S = 128 / 80 / 32: 15,063 / 5,862 / 969;
the fit's 15,063 / 5,918 / 969); the b it gives is then raised a resolution step at a time
until the true counts fit, so what is drawn (opacity and culling leave some out) stays under
the budget. When even LOD 1 everywhere does not fit, every avatar shows LOD 1.
"""

from __future__ import annotations

from archhead_addon.avatar.lod import resolution_for_lod

BISECTIONS = 30  # b to 1e-9: far below one UV resolution step


def gaussians_at(lod: float, n_max: int, s_max: int, s_min: int, n_min: int = 0) -> float:
    """The texels an avatar with n_max at S_max (LOD 0) and n_min at S_min (LOD 1) decodes
    at `lod` (n_min 0: the S^2 law alone)."""
    size = resolution_for_lod(lod, s_max, s_min)[1]
    if not n_min or s_max == s_min:
        return n_max * (size / s_max) ** 2
    # a S^2 + b S through both ends
    a = (n_max / s_max - n_min / s_min) / (s_max - s_min)
    b = n_max / s_max - a * s_max
    return a * size * size + b * size


def budget_bias(wanted: list[float], sizes: list[tuple], budget: int) -> float:
    """The smallest b >= 0 with sum of gaussians_at(min(l + b, 1)) <= budget, for levels
    `wanted` and each avatar's (n_max, s_max, s_min, n_min); 0 when they fit as they are (or
    there is no budget), 1 when nothing fits."""

    def total(b: float) -> float:
        return sum(gaussians_at(min(l + b, 1.0), *s) for l, s in zip(wanted, sizes, strict=True))

    if budget <= 0 or total(0.0) <= budget:
        return 0.0
    if total(1.0) > budget:
        return 1.0
    low, high = 0.0, 1.0
    for _ in range(BISECTIONS):
        mid = 0.5 * (low + high)
        low, high = (low, mid) if total(mid) <= budget else (mid, high)
    return high


def budgeted_lods(scene, depsgraph, objs) -> dict[int, float]:
    """Each avatar's level of detail (by session_uid) at this frame, the scene's budget
    applied; a batch render's fixed level stands as it is."""
    from .avatar_session import session
    from .scene_state import avatar_lod

    wanted, sizes, counters, uids, fixed = [], [], [], [], {}
    for obj in objs:
        avatar = session(obj)
        if avatar.lod_override is not None:
            fixed[obj.session_uid] = avatar.lod_override
            continue
        cfg = avatar.runtime.config
        wanted.append(avatar_lod(obj, depsgraph))
        n_max, n_min = avatar.shared.texels_at_ends()
        sizes.append((n_max, cfg.s_max, cfg.s_min, n_min))
        counters.append(avatar.shared.texels)
        uids.append(obj.session_uid)
    budget = scene_budget(scene)
    b = budget_bias(wanted, sizes, budget) if budget else 0.0
    if budget and b < 1.0 and sizes:  # the fit found b; the true counts have the last word
        step = 1.0 / max(max(s[1] - s[2] for s in sizes), 1)  # one UV resolution
        while b < 1.0 and exact_total(wanted, sizes, counters, b) > budget:
            b = min(b + step, 1.0)
    return {**fixed, **{u: min(l + b, 1.0) for u, l in zip(uids, wanted, strict=True)}}


def exact_total(wanted, sizes, counters, b: float) -> int:
    """The texels of every avatar at its level plus b, counted at its UV resolution."""
    return sum(
        count(resolution_for_lod(min(l + b, 1.0), s[1], s[2])[1])
        for l, s, count in zip(wanted, sizes, counters, strict=True)
    )


def scene_budget(scene) -> int:
    settings = getattr(scene, "archhead_crowd", None)
    return settings.gaussian_budget if settings is not None else 0


def scene_lods(scene, depsgraph) -> dict[int, float] | None:
    """`budgeted_lods` of every avatar in the scene, or None when it has no budget (each
    avatar then reads its own level)."""
    from .avatar_props import is_avatar

    if not scene_budget(scene):
        return None
    return budgeted_lods(scene, depsgraph, [o for o in scene.objects if is_avatar(o)])
