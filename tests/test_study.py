"""The perceptual-study kit without a browser: selection, the balanced plan, the folder, analysis and proxies."""

from __future__ import annotations

import json
import math
import shutil
from collections import Counter
from pathlib import Path
from typing import Any, Dict, List

import numpy as np
import pytest
import typer
from PIL import Image
from cli_output import unwrapped
from study_fixtures import make_study_db
from typer.testing import CliRunner

from meshadv.commands import study as study_cmd
from meshadv.experiments import ResultStore
from meshadv.study.analysis import PAPER, analyze, load_answers, write_analysis
from meshadv.study.export import export_study
from meshadv.study.plan import make_plan
from meshadv.study.proxies import attack_proxies, image_proxies, proxy_section, read_proxies
from meshadv.study.selection import MissingRenderError, job_render, select_stimuli


@pytest.fixture(scope="module")
def study_db(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_study_db(tmp_path_factory.mktemp("sweep"))


@pytest.mark.parametrize(("n", "per_image", "max_trials", "checks"), [(11, 5, 50, 0), (11, 3, 6, 1), (40, 5, 50, 3),
                                                                      (7, 2, 3, 0), (1, 4, 50, 2)])
def test_plan_is_balanced_and_never_repeats_an_image(n: int, per_image: int, max_trials: int, checks: int) -> None:
    ids = [f"img{i}" for i in range(n)]
    attention = [f"attention_{i}" for i in range(checks)]
    plan = make_plan(ids, per_image=per_image, max_trials=max_trials, attention_ids=attention, seed=4)
    counts = Counter(i for p in plan.participants for i in p.image_ids())
    assert counts == {i: per_image for i in ids}
    sizes = [len(p.trials) for p in plan.participants]
    assert max(sizes) <= max_trials and max(sizes) - min(sizes) <= 1
    # the fewest participants the cap allows
    cap = min(max_trials - checks, n)
    assert len(plan.participants) == math.ceil(n * per_image / cap)
    for p in plan.participants:
        assert len(set(p.image_ids())) == len(p.image_ids())
        assert sorted(p.image_ids(include_attention=True)[i] for i in range(len(p.trials))
                      if p.trials[i].image_id.startswith("attention_")) == attention
        firsts = [t.true_first for t in p.trials]
        assert abs(sum(firsts) - (len(firsts) - sum(firsts))) <= 1  # true class left in half of the trials
    again = make_plan(ids, per_image=per_image, max_trials=max_trials, attention_ids=attention, seed=4)
    assert again.to_record() == plan.to_record()
    if n > 2:
        other = make_plan(ids, per_image=per_image, max_trials=max_trials, attention_ids=attention, seed=5)
        assert other.to_record() != plan.to_record()


@pytest.mark.parametrize(("kwargs", "match"), [({"image_ids": []}, "image_ids"), ({"per_image": 0}, "per_image"),
                                               ({"image_ids": ["a", "a"]}, "^image_ids and attention_ids must be"),
                                               ({"max_trials": 1, "attention_ids": ["attention_0"]}, "max_trials")])
def test_plan_rejects_bad_arguments(kwargs: Dict[str, Any], match: str) -> None:
    args = {"image_ids": ["a", "b"], **kwargs}
    with pytest.raises(ValueError, match=match):
        make_plan(**args)


def test_selection_finds_successful_attacks_controls_and_checks(study_db: Path, tmp_path: Path) -> None:
    stimuli = select_stimuli(study_db, tmp_path, controls=2, attention_checks=2, seed=1)
    kinds = Counter(s.kind for s in stimuli)
    assert kinds == {"adversarial": 9, "control": 2, "attention": 2}
    with ResultStore(study_db) as store:
        ok = {r.job_id: r for r in store.rows("done") if r.record["success"]}
    for s in stimuli:
        assert Path(s.source).is_file()
        if s.kind == "adversarial":
            row = ok[s.job_id]
            assert (s.true_class, s.target) == (row.spec["source_class"], row.spec["target"])
            assert s.distance == pytest.approx(row.record["distance"]) and Path(s.source).name == "after_v0.png"
        elif s.kind == "control":
            assert s.job_id in ok and Path(s.source).name == "benign_v0.png" and s.distance is None
        else:
            assert s.true_class != s.target
            img = np.asarray(Image.open(s.source).convert("L"))
            assert img.min() < 50 and img.max() > 200  # the word is written, dark on white
    sample = select_stimuli(study_db, tmp_path, max_images=4, controls=4, seed=1)
    adv = [s.job_id for s in sample if s.kind == "adversarial"]
    assert len(adv) == 4 and adv == [s.job_id for s in stimuli if s.kind == "adversarial" and s.job_id in adv]
    assert {s.job_id for s in sample if s.kind == "control"} == set(adv)  # controls come from the attacks shown
    with pytest.raises(ValueError, match="controls"):
        select_stimuli(study_db, tmp_path, controls=10)
    with pytest.raises(ValueError, match="max_images"):
        select_stimuli(study_db, tmp_path, max_images=0)
    with pytest.raises(FileNotFoundError, match="none.db"):
        select_stimuli(tmp_path / "none.db", tmp_path)


def test_missing_render_is_made_again_or_named(study_db: Path, tmp_path: Path) -> None:
    pytest.importorskip("meshadv._raster", reason="the native renderer is not built (maturin develop --release)")
    with ResultStore(study_db) as store:
        row = next(r for r in store.rows("done") if r.record["success"])
    copy = tmp_path / "job"
    shutil.copytree(row.out_dir, copy)
    (copy / "after_v0.png").unlink()
    moved = type(row)(**{**row.__dict__, "out_dir": str(copy)})
    path = job_render(moved, "adversarial", tmp_path / "cache")
    img = np.asarray(Image.open(path).convert("RGB"))
    assert img.shape == (32, 32, 3) and img.std() > 5  # the icosphere, rendered at the job's image size
    (copy / "adversarial.ply").unlink()
    with pytest.raises(MissingRenderError, match=f"job {row.job_id}.*adversarial"):
        job_render(moved, "adversarial", tmp_path / "cache")


def test_export_writes_a_self_contained_folder(study_db: Path, tmp_path: Path) -> None:
    out = tmp_path / "study"
    study = export_study(study_db, out, per_image=3, max_trials=6, controls=2, attention_checks=1, seed=2)
    assert study.counts() == {"adversarial": 9, "control": 2, "attention": 1}
    plan = json.loads((out / "plan.json").read_text())
    js = (out / "plan.js").read_text()
    assert json.loads(js[js.index("=") + 1:].rstrip().rstrip(";")) == plan
    for name in ("index.html", "study.js", "study.css"):
        assert (out / name).is_file()
    html = (out / "index.html").read_text()
    assert "http" not in html.replace("http-equiv", "")  # nothing fetched from the network
    for image_id, stim in plan["stimuli"].items():
        assert (out / "images" / stim["file"]).is_file(), image_id
    assert plan["settings"]["exposure_ms"] == 2000.0 and plan["per_image"] == 3
    # the database is named from the study folder, so a copied folder carries no path of this machine
    assert (out / plan["settings"]["database"]).resolve() == study_db.resolve()
    assert not Path(plan["settings"]["database"]).is_absolute()
    assert len(plan["participants"]) == math.ceil(11 * 3 / 5)
    with pytest.raises(FileExistsError, match="exists and is not empty"):
        export_study(study_db, out)
    with pytest.raises(ValueError, match="post_url"):
        export_study(study_db, tmp_path / "x", post_url="ftp://example.org")
    with pytest.raises(ValueError, match="max_trials"):
        export_study(study_db, tmp_path / "y", max_trials=2, attention_checks=2)


def _answers(session: str, correct: List[bool], kind: str = "adversarial", **extra: Any) -> List[Dict[str, Any]]:
    return [{"study_id": "s", "session": session, "participant": 0, "trial": i, "image_id": f"{kind}{i}",
             "kind": kind, "correct": c, "perturbation": extra.get("perturbation", "shape"), "victim": "v1",
             "target": "chair", "distance": extra.get("distance", 0.1 * (i + 1)), "exposure_ms": 2000.0,
             "exposure_target_ms": 2000.0} for i, c in enumerate(correct)]


def test_analysis_mean_std_over_participants_and_attention_filter() -> None:
    rows = (_answers("a", [True, True, True, True]) + _answers("b", [True, False, True, True])
            + _answers("c", [False, False, False, False]) + _answers("c", [False], kind="attention")
            + _answers("a", [True], kind="attention") + _answers("b", [True], kind="control"))
    summary = analyze(rows)
    assert summary.sessions == 3 and summary.dropped_attention == 1
    overall = summary.adversarial[0]
    assert (overall.answers, overall.participants) == (8, 2)
    assert overall.mean == pytest.approx(0.875) and overall.std == pytest.approx(np.std([1.0, 0.75], ddof=1))
    assert summary.controls is not None and summary.controls.mean == 1.0
    groups = {g.group: g for g in summary.adversarial}
    assert groups["perturbation: shape"].answers == 8 and "victim: v1" in groups and "target class: chair" in groups
    bins = [g for name, g in groups.items() if name.startswith("distance: shape")]
    assert len(bins) == 3 and sum(g.answers for g in bins) == 8
    kept = analyze(rows, drop_failed_attention=False)
    assert kept.dropped_attention == 0 and kept.adversarial[0].participants == 3
    assert kept.adversarial[0].mean == pytest.approx((1.0 + 0.75 + 0.0) / 3)
    assert summary.exposure["off_target_trials"] == 0 and summary.exposure["mean_ms"] == 2000.0
    late = [{**r, "exposure_ms": 2600.0} if r["session"] == "a" and r["trial"] == 1 else r for r in rows]
    assert analyze(late).exposure["off_target_trials"] == 1  # e.g. a tab switched away during the exposure
    with pytest.raises(ValueError, match="no adversarial"):
        analyze(_answers("a", [True], kind="control"))


def test_analysis_reads_csv_and_json_once_and_writes_the_summary(tmp_path: Path) -> None:
    rows = _answers("a", [True, False, True]) + _answers("b", [True, True, True], perturbation="texture")
    (tmp_path / "a.json").write_text(json.dumps({"answers": rows}))
    header = list(rows[0])
    lines = [",".join(header)] + [",".join(str(r[k]).lower() if isinstance(r[k], bool) else str(r[k])
                                            for k in header) for r in rows]
    (tmp_path / "a.csv").write_text("\n".join(lines) + "\n")
    assert len(load_answers([tmp_path / "a.csv", tmp_path / "a.json"])) == 6
    summary = write_analysis([tmp_path / "a.csv", tmp_path / "a.json"], tmp_path / "out")
    assert summary.adversarial[0].answers == 6
    readme = (tmp_path / "out" / "README.md").read_text()
    assert f"{PAPER['mean_pct']:.2f} ± {PAPER['std_pct']:.2f}%" in readme and "| 3820 | 49 |" in readme
    assert "perturbation: texture" in readme
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["adversarial"][0]["answers"] == 6
    fig = np.asarray(Image.open(tmp_path / "out" / "true_class_share.png").convert("L"))
    assert fig.shape[0] > 100 and fig.std() > 1.0
    (tmp_path / "bad.csv").write_text("a,b\n1,2\n")
    with pytest.raises(ValueError, match="study answers"):
        load_answers([tmp_path / "bad.csv"])


def test_image_proxies_order_distortions() -> None:
    rng = np.random.default_rng(0)
    clean = (rng.random((32, 32, 3)) * 255).astype(np.uint8)
    small = np.clip(clean.astype(int) + rng.integers(-3, 4, clean.shape), 0, 255).astype(np.uint8)
    large = np.clip(clean.astype(int) + rng.integers(-60, 61, clean.shape), 0, 255).astype(np.uint8)
    s_small, p_small = image_proxies(clean, small)
    s_large, p_large = image_proxies(clean, large)
    assert 1.0 > s_small > s_large and p_small > p_large
    mse = np.mean((clean.astype(float) - small.astype(float)) ** 2)
    assert p_small == pytest.approx(10 * np.log10(255 ** 2 / mse))
    assert image_proxies(clean, clean) == (1.0, math.inf)
    with pytest.raises(ValueError, match="^benign and adversarial images must have the same shape"):
        image_proxies(clean, clean[:16])


def test_proxy_section_covers_every_attack(study_db: Path, tmp_path: Path) -> None:
    with ResultStore(study_db) as store:
        rows = store.rows("done")
    proxies, missing = attack_proxies(rows)
    assert len(proxies) == 12 and missing == 0
    text = proxy_section(rows, tmp_path)
    assert "| v1 | shape |" in text and "| v1 | texture |" in text
    assert len((tmp_path / "proxies.csv").read_text().splitlines()) == 13


def test_proxies_of_attacks_without_renders_are_kept_from_the_last_report(tmp_path: Path) -> None:
    db = make_study_db(tmp_path / "sweep")  # its own: renders are deleted below
    with ResultStore(db) as store:
        rows = store.rows("done")
    proxy_section(rows, tmp_path)
    before = (tmp_path / "proxies.csv").read_text()
    for row in rows[:5]:  # another machine: these renders are not there
        for name in row.record["artifacts"]["adversarial_images"]:
            (Path(row.out_dir) / name).unlink()
    assert attack_proxies(rows)[1] == 5  # without the earlier values: 5 missing
    text = proxy_section(rows, tmp_path)
    assert (tmp_path / "proxies.csv").read_text() == before and "no renders on disk" not in text
    assert read_proxies(tmp_path / "proxies.csv")[rows[0].job_id][2] >= 1


def test_study_commands(study_db: Path, tmp_path: Path) -> None:
    app = typer.Typer()
    study_cmd.register(app)
    runner = CliRunner()
    res = runner.invoke(app, ["study", "export", str(study_db), "-o", str(tmp_path / "s"), "--per-image", "2",
                              "--max-trials", "10", "--attention-checks", "1", "--controls", "1", "--seed", "3",
                              "--max-images", "7"])
    assert res.exit_code == 0, res.output
    assert "7 adversarial images, 1 controls, 1 attention checks; 2 participants" in res.output
    res = runner.invoke(app, ["study", "export", str(tmp_path / "missing.db"), "-o", str(tmp_path / "t")])
    assert res.exit_code == 2 and "does not exist" in unwrapped(res.output)
    (tmp_path / "a.json").write_text(json.dumps(_answers("a", [True, False])))
    res = runner.invoke(app, ["study", "analyze", str(tmp_path / "a.json"), "-o", str(tmp_path / "an")])
    assert res.exit_code == 0, res.output
    assert "50.00 ± 0.00%" in res.output and (tmp_path / "an" / "README.md").is_file()
    res = runner.invoke(app, ["study", "analyze", str(tmp_path / "nope.csv"), "-o", str(tmp_path / "an")])
    assert res.exit_code == 2 and "missing answer files" in res.output


def test_sweep_report_shows_the_proxies(study_db: Path, tmp_path: Path) -> None:
    from meshadv.commands.report import write_full_report

    out = write_full_report(study_db, tmp_path / "report", figures=False)
    readme = (tmp_path / "report" / "README.md").read_text()
    assert "## Perceptual proxies: SSIM and PSNR" in readme and "| v1 | texture | 3 |" in readme
    assert tmp_path / "report" / "proxies.csv" in out.tables
