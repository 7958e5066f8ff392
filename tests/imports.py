"""Which modules a piece of code loads, run in a fresh interpreter (for the checks
that vdad models only what a scene needs)."""

import subprocess
import sys


def loaded(code, modules):
    """The names of ``modules`` that are in ``sys.modules`` after ``code`` runs in a new
    Python process."""
    probe = f"{code}\nimport sys\nprint([m for m in {list(modules)!r} if m in sys.modules])"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         check=True)
    return out.stdout.strip().splitlines()[-1]
