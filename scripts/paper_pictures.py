"""The paper's pictures, rendered by vdad (issue 16): Kim 2008 Figures 1 and 7
(the falling character seen at increasing distances, one colour per rigid group,
as motion strips) and Figure 2 (the dog puppet walking behind a wall, its
hidden legs rigid), with the active joints marked in red.

Each picture is one ``vdad render`` command (printed before it runs), so a
reader can rerun or vary it. Writes ``docs/pictures/*.png`` (the README shows
the first). Usage: ``python scripts/paper_pictures.py [OUT_DIR]``; needs the
``render`` extra and EGL.
"""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

from vdad.cli import main as vdad

PICTURES = {
    # Figures 1 and 7: the same fall simulated three times, the viewer 3, 12 and
    # 30 m away (rows, all drawn from 3 m): farther away, fewer and larger groups
    "figure1_character_distances.png": [
        "render", "falling_character", "--method", "view-bvh", "--pixels", "moved",
        "--threshold", "0.003", "--steps", "2500", "--strip", "6",
        "--distances", "3,12,30", "--show-active", "--size", "320x240"],
    # Figure 2: the puppet walks behind the wall; occlusion queries see its legs
    # hidden and make them rigid while its head and back stay articulated
    "figure2_puppet_behind_wall.png": [
        "render", "dog_puppet", "--method", "view-oq", "--counting", "merged",
        "--threshold", "0.03", "--steps", "3000", "--strip", "6", "--show-active",
        "--size", "320x240"],
}


def main(out="docs/pictures"):
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for name, argv in PICTURES.items():
        argv = [*argv, "--out", str(out / name), "--no-progress"]
        print("vdad " + shlex.join(argv), flush=True)
        if vdad(argv) != 0:
            raise SystemExit(f"vdad render failed for {name}")


if __name__ == "__main__":
    main(*sys.argv[1:])
