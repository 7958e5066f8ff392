"""Every method runs with nothing but its name (docs/scenes.md, method defaults), through
the API and the command line, and every ``vdad`` command line written in README.md and
docs/*.md runs (with few steps)."""

import json
import re
from pathlib import Path

import numpy as np
import pytest

from vdad.cli import build_parser, main
from vdad.scenes import SCENES, hanging_dogs
from vdad.simulator import METHODS

ROOT = Path(__file__).resolve().parents[1]
DOCUMENTS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


# --- the documented defaults ---------------------------------------------------------

def documented_defaults():
    """{(scene, method): {option: value}} from the table of docs/scenes.md's "Method
    defaults": rows ``| `scene` | `method` | option value[, option value] | ...``."""
    text = (ROOT / "docs" / "scenes.md").read_text()
    if "## Method defaults" not in text:
        return {}
    section = text.split("## Method defaults", 1)[1].split("\n## ", 1)[0]
    table = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 3 or not cells[0].startswith("`"):
            continue
        scene, method = cells[0].strip("`"), cells[1].strip("`")
        options = {}
        for pair in cells[2].split(","):
            key, value = pair.split()[:2]
            options[key] = float(value) if re.fullmatch(r"[-+.\deE]+", value) else value
        table[scene, method] = options
    return table


DEFAULTS = documented_defaults()


def test_the_table_covers_every_scene_and_method():
    assert set(DEFAULTS) == {(s, m) for s in SCENES for m in METHODS if m != "dca"}


def assert_documented(scene, method, options):
    """``options`` (a simulator's) hold the documented defaults of ``method`` on
    ``scene`` (4 significant digits, as the table prints them)."""
    if method == "dca":
        assert options == {}
        return
    for key, value in DEFAULTS[scene, method].items():
        if isinstance(value, float):
            assert options[key] == pytest.approx(value, rel=1e-3), (scene, method, key)
        else:
            assert options[key] == value, (scene, method, key)
    assert ("threshold" in options) != ("budget" in options)


SMALL = {"hanging_dogs": ["--dogs", "2"]}           # the 100 dogs: once, through the API


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("name", sorted(SCENES))
def test_every_method_runs_with_defaults_from_the_command_line(name, method, tmp_path):
    out = tmp_path / "run.json"
    assert main(["run", name, *SMALL.get(name, []), "--method", method, "--steps", "4",
                 "--json", str(out), "--no-progress"]) == 0
    data = json.loads(out.read_text())
    assert_documented(name, method, data["options"])
    assert data["steps"] == 4 and np.all(np.isfinite(data["final_q"] + data["final_qd"]))


@pytest.mark.parametrize("method", ["adaptive", "view-bvh", "lod-distance", "sleeping"])
def test_the_hundred_dogs_run_with_defaults(method):
    scene = hanging_dogs()
    sim = scene.simulator(method=method)
    assert_documented("hanging_dogs", method, sim.options)
    sim.step(2)
    assert np.all(np.isfinite(sim.q)) and np.all(np.isfinite(sim.qd))


def test_the_summary_line_shows_the_options_used(capsys):
    assert main(["run", "pendulum", "--method", "lod-distance", "--steps", "2",
                 "--no-progress"]) == 0
    out = capsys.readouterr().out
    shown = re.search(r"with lod-distance \(distance ([\d.]+) m; semi-implicit\)", out)
    assert shown, out
    assert float(shown[1]) == pytest.approx(DEFAULTS["pendulum", "lod-distance"]["distance"],
                                            rel=1e-3)


# --- the command lines of the documentation ------------------------------------------

PLACEHOLDERS = {"SCENE": "pendulum", "METHOD": "adaptive", "FILE": "out.png", "DIR": "results",
                "PATH": "out.json", "MODEL.xml": str(ROOT / "tests" / "data" / "arm.xml"),
                "D": "3", "N": "3"}
SMALL_STEPS = "5"


def _code_lines(text):
    """Shell command lines of ``text`` (Markdown): the lines of fenced code blocks
    (backslash continuations joined, comments cut) and the inline code spans, each
    split at ``&&``, ``;`` and ``|``."""
    fenced = re.findall(r"^```[^\n]*\n(.*?)^```", text, flags=re.S | re.M)
    lines = [line for block in fenced for line in block.replace("\\\n", " ").splitlines()]
    prose = re.sub(r"^```[^\n]*\n.*?^```", "", text, flags=re.S | re.M)
    lines += [span.replace("\n", " ") for span in re.findall(r"`([^`]+)`", prose)]
    return [part.strip() for line in lines for part in re.split(r"&&|;|\|", line.split(" #")[0])]


def documented_commands():
    """``(document, command)`` for every ``vdad`` command line of README.md and
    docs/*.md, and every option example that starts with ``--method`` (as
    ``vdad run SCENE ...``)."""
    out = []
    for doc in DOCUMENTS:
        for line in _code_lines(doc.read_text()):
            if line.startswith("--method "):
                line = "vdad run SCENE " + line
            match = re.match(r"(?:\.venv/bin/)?vdad (.*)", " ".join(line.split()))
            if match and (doc.name, match[1]) not in out:
                out.append((doc.name, match[1]))
    return out


COMMANDS = documented_commands()


def test_the_documentation_has_commands():
    """The extraction finds the commands it must (a broken one finds none)."""
    found = {c for _, c in COMMANDS}
    assert "run pendulum --bodies 20 --steps 500 --json pendulum.json" in found
    assert any(c.startswith("render dog_puppet") for c in found)
    assert any(c.startswith("reproduce") for c in found)


def instantiate(command):
    """``command`` (after ``vdad``) as an argv to run here: placeholders
    (:data:`PLACEHOLDERS`, ``--method ...``, optional ``[...]``, the scene and
    output of a bare ``vdad render``) filled in, few steps, small pictures, no
    progress bars."""
    command = re.sub(r"\[([^\]]*)\]", r"\1", command)            # [--quick]: given
    command = command.replace("--method ...", "--method adaptive")
    argv = [PLACEHOLDERS.get(word, word) for word in command.split() if word != "..."]
    unknown = [w for w in argv if re.fullmatch(r"[A-Z][A-Z_]*", w)]
    assert not unknown, f"add {unknown} to PLACEHOLDERS"
    if argv[0] in ("run", "render") and "--help" not in argv:
        if len(argv) < 2 or (argv[1] not in SCENES             # `vdad render`: a name
                             and not argv[1].endswith(".xml")):
            argv.insert(1, PLACEHOLDERS["SCENE"])
        if argv[0] == "render" and "--out" not in argv:
            argv += ["--out", PLACEHOLDERS["FILE"]]
        if "--steps" in argv:
            argv[argv.index("--steps") + 1] = SMALL_STEPS
        else:
            argv += ["--steps", SMALL_STEPS]
        if "--every" in argv:
            argv[argv.index("--every") + 1] = "1"
        if argv[0] == "render" and "--size" not in argv:
            argv += ["--size", "64x48"]
    return argv + ["--no-progress"] if "--help" not in argv else argv


def test_instantiate():
    assert instantiate("render SCENE --method ... --out FILE") == [
        "render", "pendulum", "--method", "adaptive", "--out", "out.png", "--steps", "5",
        "--size", "64x48", "--no-progress"]
    assert instantiate("reproduce [--quick] [--out results]") == [
        "reproduce", "--quick", "--out", "results", "--no-progress"]
    assert instantiate("render") == ["render", "pendulum", "--out", "out.png", "--steps", "5",
                                     "--size", "64x48", "--no-progress"]
    with pytest.raises(AssertionError, match="PLACEHOLDERS"):
        instantiate("run SCENE --out WHERE")


@pytest.mark.parametrize("doc, command", COMMANDS, ids=[f"{d}: vdad {c}" for d, c in COMMANDS])
def test_documented_command_runs(doc, command, tmp_path, monkeypatch, capsys):
    argv = instantiate(command)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "docs").mkdir()
    if argv[0] == "reproduce":
        # a reproduction runs for minutes even --quick: tests/test_reproduce.py runs
        # `vdad reproduce --quick`; here the options must parse
        args = build_parser().parse_args(argv)
        assert args.command == "reproduce"
        assert '"reproduce", "--quick"' in (ROOT / "tests" / "test_reproduce.py").read_text()
        return
    try:
        code = main(argv)
    except SystemExit as exc:                                   # --help
        code = exc.code
    assert code == 0, (doc, argv, capsys.readouterr().err)
