"""The real attack job (renderer + victim + attack) in a tiny sweep, and every figure drawn from its results."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from sweep_fixtures import tiny_builtin_config

from meshadv.experiments import ResultStore, SerialBackend, run_sweep
from meshadv.experiments.config import expand_jobs, parse_config
from meshadv.experiments.report import write_report

pytest.importorskip("meshadv._raster", reason="the native renderer is not built (maturin develop --release)")

TINY = tiny_builtin_config("tiny-attack")


@pytest.mark.slow
def test_attack_job_sweep_and_report(tmp_path: Path) -> None:
    try:
        from meshadv.victims import load_victim

        load_victim("efficientnet_lite0")
    except ImportError as err:  # the package is missing; broken weights must fail, not skip
        pytest.skip(f"victim efficientnet_lite0 unavailable: {err}")
    jobs = expand_jobs(parse_config(TINY))
    assert len(jobs) == 4
    store = ResultStore(tmp_path / "r.db")
    summary = run_sweep(store, jobs, "meshadv.experiments.jobs:run_attack_job", out_root=tmp_path / "run",
                        backend=SerialBackend(), max_attempts=1, progress=False)
    errors = [r.error for r in store.rows("failed")]
    assert summary.done == 4, errors
    for row in store.rows():
        rec = row.record
        assert isinstance(rec["success"], bool) and rec["steps"] >= 1 and rec["time"] > 0
        key = "laplacian_pair_mean" if row.spec["perturbation"] == "shape" else "color_rmse"
        assert rec["distance"] == pytest.approx(rec["distances"][key])
        assert rec["distance"] >= 0.0
        if row.spec["perturbation"] == "shape":  # the Laplacian is zero exactly when nothing moved
            assert (rec["distance"] > 0) == (rec["distances"]["max_displacement"] > 0)
        out = Path(row.out_dir)
        for name in ("benign.ply", "benign_v0.png", "adversarial.ply", "after_v0.png", "result.json"):
            assert (out / name).is_file(), name
    store.close()
    rep = write_report(tmp_path / "r.db", tmp_path / "report")
    names = {p.name for p in rep.figures}
    assert names == {"grid_efficientnet_lite0_shape.png", "grid_efficientnet_lite0_texture.png",
                     "flow_heatmap_efficientnet_lite0.png", "flow_quiver_efficientnet_lite0.png",
                     "curvature_efficientnet_lite0.png"}
    for path in rep.figures:
        assert np.asarray(Image.open(path).convert("L")).std() > 1.0


def test_attack_job_required_margin_wraps_the_criterion(tmp_path: Path) -> None:
    import json

    from meshadv.experiments.jobs import run_attack_job

    try:
        from meshadv.victims import load_victim

        load_victim("efficientnet_lite0")
    except ImportError as err:  # the package is missing; broken weights must fail, not skip
        pytest.skip(f"victim efficientnet_lite0 unavailable: {err}")
    spec = next(j for j in expand_jobs(parse_config(TINY)) if j["perturbation"] == "texture")
    records = {}
    for margin in (0.0, 1000.0):
        out = tmp_path / f"m{margin:g}"
        out.mkdir()
        job = {**spec, "attack": {**spec["attack"], "steps": 2, "required_margin": margin}}
        records[margin] = (run_attack_job(job, out), json.loads((out / "result.json").read_text()))
    plain, plain_json = records[0.0]
    strict, strict_json = records[1000.0]
    assert "required_margin" not in plain_json["criteria"][0]
    assert strict_json["criteria"][0]["required_margin"] == 1000.0
    assert strict_json["criteria"][0]["criterion"] == "WithMargin(TargetedMisclassification)"
    assert strict["success"] is False  # no render leads its runner-up by 1000 logits
    margins = np.asarray(strict_json["margins"][0])
    assert (margins < 0).all() and (margins < np.asarray(plain_json["margins"][0])).all()


def test_job_context_benign_verdict_is_the_jobs_own_check(tmp_path: Path) -> None:
    """``JobContext.benign_verdict`` gives the verdict the job
    records, and a job told to attack only right renders skips exactly when that verdict is wrong."""
    from meshadv.experiments.jobs import JobContext, load_job_mesh, run_attack_job

    try:
        from meshadv.victims import load_victim

        load_victim("efficientnet_lite0")
    except ImportError as err:  # the package is missing; broken weights must fail, not skip
        pytest.skip(f"victim efficientnet_lite0 unavailable: {err}")
    spec = next(j for j in expand_jobs(parse_config(TINY)) if j["perturbation"] == "texture")
    job = {**spec, "attack": {**spec["attack"], "steps": 1}, "benign_correct_only": True}
    verdict = JobContext.from_spec(job).benign_verdict(load_job_mesh(job["mesh"]))
    assert len(verdict.top1) == len(job["views"]) == verdict.images.shape[0]
    assert verdict.correct == all(label == job["source_class"] for label in verdict.top1)
    record = run_attack_job(job, tmp_path)
    assert record["benign_correct"] == verdict.correct and record["benign_top1"] == verdict.top1
    assert record["skipped"] is (not verdict.correct)


def test_multiview_job_skips_a_mesh_wrong_on_its_unseen_views(tmp_path: Path,
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    """A multi-view job judges its unseen views benignly too; with ``benign_correct_only`` a mesh right on every
    attack view but wrong on an unseen one is skipped, and without it the job runs and records both verdicts."""
    import torch

    from meshadv.experiments.jobs import BenignVerdict, JobContext, run_attack_job

    try:
        from meshadv.victims import load_victim

        load_victim("efficientnet_lite0")
    except ImportError as err:
        pytest.skip(f"victim efficientnet_lite0 unavailable: {err}")
    config = {**TINY, "attack": {**TINY["attack"], "perturbations": ["texture"]},
              "multiview": {"enabled": True, "view_counts": [2], "azimuth_ranges": [[40, 60]], "eval_views": 3,
                            "perturbations": ["texture"], "targets": {"chair": "sofa", "sofa": "chair"}}}
    spec = next(j for j in expand_jobs(parse_config(config)) if j["kind"] == "multiview")
    assert spec["benign_correct_only"] is False  # the default keeps the jobs of existing sweeps as they were
    judged = []

    def verdict(self: JobContext, mesh: object, views: object = None) -> BenignVerdict:
        unseen = views is not None
        count = len(views) if unseen else len(self.views)
        judged.append(count)
        label = "sofa" if unseen else self.spec["source_class"]  # right on the attack views, wrong on the unseen
        return BenignVerdict(correct=not unseen, top1=[label] * count, images=torch.zeros(count, 3, 32, 32))

    monkeypatch.setattr(JobContext, "benign_verdict", verdict)
    job = {**spec, "attack": {**spec["attack"], "steps": 1}}
    kept = run_attack_job({**job, "benign_correct_only": True}, tmp_path / "filtered")
    assert judged == [2, 3]
    assert kept["skipped"] is True and kept["benign_correct"] is True and kept["benign_unseen_correct"] is False
    assert "unseen views" in kept["reason"] and kept["benign_unseen_top1"] == ["sofa"] * 3
    ran = run_attack_job(job, tmp_path / "all")
    assert ran["skipped"] is False and ran["steps"] >= 1 and ran["benign_unseen_correct"] is False
    assert ran["eval_success_rate"] is not None


def test_an_interrupted_attack_job_records_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Ctrl-C in a job's attack (the attack keeps its best so far) propagates: a job cut short is not a result, so
    that a serial sweep re-queues it and a report's regeneration is not taken for the job's artefacts."""
    from meshadv.experiments import jobs, worker

    try:
        from meshadv.victims import load_victim

        load_victim("efficientnet_lite0")
    except ImportError as err:
        pytest.skip(f"victim efficientnet_lite0 unavailable: {err}")
    spec = next(j for j in expand_jobs(parse_config(TINY)) if j["perturbation"] == "texture")

    def interrupt(info: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(worker, "attack_step_callback", interrupt)
    with pytest.raises(KeyboardInterrupt, match="interrupted after"):
        jobs.run_attack_job({**spec, "attack": {**spec["attack"], "steps": 5}}, tmp_path)
    assert not (tmp_path / "result.json").exists()
