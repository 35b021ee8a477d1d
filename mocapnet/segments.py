"""Body segments (left-arm, right-leg, …) for marker sets and skeletons, used by segment gaps.

Plug-in-Gait markers (PROTOCOL.md): left arm = LUPA LELB LFRM LWRA LWRB LFIN, left leg = LTHI LKNE LSHN
(or LTIB) LANK LHEE LTOE, right side with R. For a skeleton: the joints of the arm chain below the
shoulder and of the leg chain below the hip.
"""

from __future__ import annotations

import re

from mocapnet.motion import Skeleton

SEGMENTS = ("left-arm", "right-arm", "arms", "left-leg", "right-leg", "legs")

_PIG = {
    "arm": ("UPA", "ELB", "FRM", "FRA", "WRA", "WRB", "FIN"),
    "leg": ("THI", "KNE", "SHN", "TIB", "ANK", "HEE", "TOE", "MT5"),
}


def _sides(segment: str) -> list[tuple[str, str]]:
    if segment not in SEGMENTS:
        raise ValueError(f"unknown segment {segment!r}; choose one of {', '.join(SEGMENTS)}")
    limb = "arm" if "arm" in segment else "leg"
    if segment.startswith("left"):
        return [("L", limb)]
    if segment.startswith("right"):
        return [("R", limb)]
    return [("L", limb), ("R", limb)]


def marker_segment(labels: tuple[str, ...] | list[str], segment: str) -> list[int]:
    """Indices of the Plug-in-Gait style markers of ``segment`` among ``labels`` (``Subject:`` prefixes
    ignored). Raises ValueError naming the segment when no label matches."""
    bare = [lab.rsplit(":", 1)[-1].upper() for lab in labels]
    wanted = {side + suffix for side, limb in _sides(segment) for suffix in _PIG[limb]}
    idx = [i for i, b in enumerate(bare) if b in wanted]
    if not idx:
        raise ValueError(f"no marker of segment {segment!r} among labels {list(labels)[:8]}…")
    return idx


def _is_side(name: str, side: str) -> bool:
    n = name.lower()
    word = "left" if side == "L" else "right"
    return word in n or bool(re.search(rf"(^{side.lower()}[a-z_]|[_.]{side.lower()}$|_{side.lower()}_)", n))


def skeleton_segment(skeleton: Skeleton, segment: str) -> list[int]:
    """Joint indices of ``segment``: every joint below the shoulder (arm) or hip (leg) of that side.

    The chain starts at the first joint named like an upper arm (``UpperArm``, ``Arm``, ``Shoulder``'s
    child) or upper leg (``UpLeg``, ``UpperLeg``, ``Thigh``) on that side.
    """
    names = skeleton.names
    keys = {
        "arm": ("upperarm", "leftarm", "rightarm", "arm_", "humerus"),
        "leg": ("upleg", "upperleg", "thigh", "femur"),
    }
    out: list[int] = []
    for side, limb in _sides(segment):
        starts = [j for j, n in enumerate(names) if _is_side(n, side) and any(k in n.lower() + "_" for k in keys[limb])]
        if not starts:
            raise ValueError(f"skeleton has no {('left' if side == 'L' else 'right')} {limb} joint: {names}")
        start = starts[0]
        stack = [start]
        while stack:
            j = stack.pop()
            out.append(j)
            stack.extend(skeleton.children[j])
    return sorted(out)
