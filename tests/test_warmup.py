"""vdad.warmup (``vdad compile``): the kernels compiled ahead of a first run, in
processes of their own."""

import io

import pytest

from vdad.cli import main
from vdad.errors import VdadError
from vdad.warmup import PARTS, compile_kernels


def test_a_part_compiles_in_its_own_process_and_says_so():
    out = io.StringIO()
    seconds = compile_kernels(1, ("coverage",), out=out)
    assert seconds > 0
    assert out.getvalue().startswith("vdad compile: coverage done after ")
    assert "failed" not in out.getvalue()


@pytest.mark.parametrize("jobs", [0, -1, 1.5, True])
def test_jobs_must_be_a_positive_whole_number(jobs):
    with pytest.raises(VdadError, match="jobs must be a positive whole number"):
        compile_kernels(jobs)


def test_unknown_parts_are_named():
    with pytest.raises(VdadError, match=r"unknown kernel parts \['kinematic'\]"):
        compile_kernels(2, ("coverage", "kinematic"))
    assert set(PARTS) == {"loop", "raster loop", "adaptive", "dynamics", "coverage"}


def test_the_command_rejects_zero_jobs(capsys):
    with pytest.raises(SystemExit):
        main(["compile", "--jobs", "0"])
    assert "--jobs" in capsys.readouterr().err
