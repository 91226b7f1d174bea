"""Robot URDFs for tests: the example-robot-data xArm 7 copied where a test wants it, as it is
or edited (a comment added: the same dynamics; a link's mass changed: other dynamics)."""

from __future__ import annotations

import re
from pathlib import Path


def xarm_urdf(path: Path, *, comment: bool = False, heavier: bool = False) -> Path:
    """The xArm 7 URDF written to ``path``: byte for byte, or with a comment added
    (``comment``), or with its first link 10 % heavier (``heavier``)."""
    from twincd.twin.robot import resolve_urdf

    text = resolve_urdf("xarm7").read_text()
    if heavier:
        masses = list(re.finditer(r'<mass value="([0-9.]+)"', text))
        first = masses[1]  # link1's (the first is the base's, which the twin does not move)
        value = float(first.group(1)) * 1.1
        text = text[: first.start(1)] + f"{value:.6g}" + text[first.end(1) :]
    if comment:
        text += "\n<!-- edited: a comment only -->\n"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path
