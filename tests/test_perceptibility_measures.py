"""The perceptibility measures against hand-computed cases: vertex moves, face-normal and face-colour changes, SSIM
of renders, the held-out views, and their place in an attack's result, summary and comparison footer."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from meshadv.perceptibility import (
    color_changes,
    edge_strains,
    held_out_views,
    normal_changes,
    perceptibility_measures,
    render_ssim,
    surface_measures,
    vertex_moves,
)
from meshadv.render import Camera, Lights, RenderSetup, ViewSet, native_available

needs_native = pytest.mark.skipif(not native_available(), reason="native module meshadv._raster not built")


def test_vertex_moves_max_and_linear_95th_percentile() -> None:
    # 21 vertices on a line of length 20 along x (diagonal 20); vertex i moves by i / 10 along z
    vertices = torch.stack([torch.arange(21.0), torch.zeros(21), torch.zeros(21)], dim=1)
    moved = vertices.clone()
    moved[:, 2] = torch.arange(21.0) / 10
    got = vertex_moves(moved, vertices)
    assert float(got["max_displacement"][0]) == pytest.approx(2.0 / 20)
    # sorted moves 0, 0.1, ..., 2.0: the 95th percentile sits at position 0.95 * 20 = 19, i.e. 1.9
    assert float(got["p95_displacement"][0]) == pytest.approx(1.9 / 20)
    batch = vertex_moves(torch.stack([vertices, moved]), vertices)["max_displacement"]
    assert batch.tolist() == pytest.approx([0.0, 0.1])


def test_vertex_moves_reject_bad_shapes_and_flat_meshes() -> None:
    with pytest.raises(ValueError, match="vertices_adv"):
        vertex_moves(torch.zeros(3, 3), torch.rand(4, 3))
    with pytest.raises(ValueError, match="zero extent"):
        vertex_moves(torch.ones(3, 3), torch.ones(3, 3))


def _two_triangles() -> tuple[torch.Tensor, torch.Tensor]:
    """Two separate right triangles in z = 0: face 0 of area 1/2 (legs 1), face 1 of area 9/2 (legs 3)."""
    vertices = torch.tensor([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 0, 0], [8, 0, 0], [5, 3, 0]])
    return vertices, torch.tensor([[0, 1, 2], [3, 4, 5]])


def test_normal_changes_are_area_weighted_angles() -> None:
    vertices, faces = _two_triangles()
    moved = vertices.clone()
    moved[2, 2] = 1.0  # face 0: corner (0, 1, 0) lifted to (0, 1, 1): the normal turns by 45 degrees
    got = normal_changes(moved, vertices, faces)
    # weights 1/2 and 9/2: mean = (0.5 * 45 + 4.5 * 0) / 5 = 4.5 degrees
    assert float(got["normal_change_mean_deg"][0]) == pytest.approx(4.5, abs=1e-4)
    # face 1 (unchanged) covers 90% of the area, less than 95%: the percentile reaches face 0's 45 degrees
    assert float(got["normal_change_p95_deg"][0]) == pytest.approx(45.0, abs=1e-4)
    lifted = vertices.clone()
    lifted[5, 2] = 3.0  # the big face turns by 45 degrees instead: 90% of the area at 45
    both = normal_changes(torch.stack([moved, lifted]), vertices, faces)
    assert both["normal_change_mean_deg"].tolist() == pytest.approx([4.5, 40.5], abs=1e-4)
    assert both["normal_change_p95_deg"].tolist() == pytest.approx([45.0, 45.0], abs=1e-4)


def test_a_folded_face_turns_180_and_a_collapsed_one_counts_90() -> None:
    vertices, faces = _two_triangles()
    folded = vertices.clone()
    folded[[1, 2]] = folded[[2, 1]]  # face 0's winding reversed: folded over
    collapsed = vertices.clone()
    collapsed[5] = collapsed[3]  # face 1 loses its area
    got = normal_changes(torch.stack([folded, collapsed]), vertices, faces)
    assert got["normal_change_mean_deg"].tolist() == pytest.approx([0.1 * 180, 0.9 * 90], abs=1e-4)
    assert got["normal_change_p95_deg"].tolist() == pytest.approx([180.0, 90.0], abs=1e-4)


def test_uniform_scaling_moves_vertices_but_turns_no_normal() -> None:
    vertices, faces = _two_triangles()
    got = surface_measures(vertices * 1.1, torch.zeros(2, 3), vertices, torch.zeros(2, 3), faces)
    diagonal = math.sqrt(8**2 + 3**2)
    assert got["max_displacement"] == pytest.approx(0.8 / diagonal, rel=1e-6)  # vertex (8, 0, 0) moves by 0.8
    assert got["normal_change_mean_deg"] == pytest.approx(0.0, abs=1e-3)
    assert got["normal_change_p95_deg"] == pytest.approx(0.0, abs=1e-3)
    assert got["color_change_p95"] == 0.0


def test_edge_strain_is_the_length_weighted_95th_percentile_of_the_edges_relative_change() -> None:
    v = torch.tensor([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    f = torch.tensor([[0, 1, 2], [1, 3, 2]])  # 5 edges: 4 sides of length 1, the diagonal 1-2 of length sqrt 2
    moved = v.clone()
    moved[3, 0] = 1.5  # edge 1-3 becomes sqrt(1.25), edge 2-3 becomes 1.5, the other three keep their lengths
    # strains by length: 0 over 2 + sqrt 2, 0.118 over 1, 0.5 over 1 (18% of the length): the 95th percentile is 0.5
    got = edge_strains(torch.stack([v, moved]), v, f)["edge_strain_p95"]
    assert got.tolist() == pytest.approx([0.0, 0.5], abs=1e-6)
    # a short edge doubling holds under 5% of the length: the percentile is the long edge's small strain
    sliver = torch.tensor([[0.0, 0, 0], [1, 0, 0], [0, 0.02, 0]])
    widened = sliver.clone()
    widened[2, 1] = 0.04
    want = math.sqrt(1 + 0.04 ** 2) / math.sqrt(1 + 0.02 ** 2) - 1  # edge 1-2; edge 0-2 (strain 1) is 1% of the length
    got = edge_strains(widened, sliver, torch.tensor([[0, 1, 2]]))["edge_strain_p95"]
    assert float(got[0]) == pytest.approx(want, rel=1e-4)


def test_the_largest_edge_strain_is_the_worst_single_edge_however_short() -> None:
    v = torch.tensor([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    f = torch.tensor([[0, 1, 2], [1, 3, 2]])
    moved = v.clone()
    moved[3, 0] = 1.5  # edge 2-3: 1 -> 1.5 (0.5), edge 1-3: 1 -> sqrt(1.25) (0.118)
    got = edge_strains(torch.stack([v, moved]), v, f)["edge_strain_max"]
    assert got.tolist() == pytest.approx([0.0, 0.5], abs=1e-6)
    # the short edge 0-2 of a sliver stretched 0.02 -> 0.08 (strain 3), under 5% of the length: the percentile
    # keeps the long edges' strain, the largest is 3
    sliver = torch.tensor([[0.0, 0, 0], [1, 0, 0], [0, 0.02, 0]])
    opened = sliver.clone()
    opened[2, 1] = 0.08
    strains = edge_strains(opened, sliver, torch.tensor([[0, 1, 2]]))
    assert float(strains["edge_strain_max"][0]) == pytest.approx(3.0, rel=1e-5)
    assert float(strains["edge_strain_p95"][0]) == pytest.approx(math.sqrt(1 + 0.08 ** 2) / math.sqrt(1 + 0.02 ** 2)
                                                                 - 1, rel=1e-4)
    # an edge shorter than 0.25% of the diagonal counts as that long: 0.0001 -> 0.0011 over 0.0025 x the diagonal
    micro = torch.tensor([[0.0, 0, 0], [1, 0, 0], [0, 0.0001, 0]])
    grown = micro.clone()
    grown[2, 1] = 0.0011
    diagonal = math.sqrt(1 + 0.0001 ** 2)
    got = edge_strains(grown, micro, torch.tensor([[0, 1, 2]]))["edge_strain_max"]
    assert float(got[0]) == pytest.approx(0.001 / (0.0025 * diagonal), rel=1e-4)


def test_edge_strain_ignores_rigid_motion_and_gives_a_uniform_scale_its_factor() -> None:
    from meshadv.mesh import builtin_mesh

    mesh = builtin_mesh("chair")
    c, s = math.cos(0.7), math.sin(0.7)
    rotation = torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    moved = mesh.vertices @ rotation.T + torch.tensor([0.3, -0.2, 0.1])
    assert float(edge_strains(moved, mesh.vertices, mesh.faces)["edge_strain_p95"][0]) == pytest.approx(0, abs=1e-5)
    grown = edge_strains(mesh.vertices * 1.2, mesh.vertices, mesh.faces)["edge_strain_p95"]
    assert float(grown[0]) == pytest.approx(0.2, rel=1e-4)
    with pytest.raises(ValueError, match="zero length"):
        edge_strains(torch.zeros(3, 3), torch.zeros(3, 3), torch.tensor([[0, 1, 2]]))
    with pytest.raises(ValueError, match="faces"):
        edge_strains(mesh.vertices, mesh.vertices, torch.zeros(0, 3, dtype=torch.long))


def test_color_change_percentile_is_area_weighted() -> None:
    vertices, faces = _two_triangles()
    colors = torch.full((2, 3), 0.5)
    small = colors.clone()
    small[0] = torch.tensor([1.0, 0.5, 0.5])  # the small face (10% of the area) changes by 0.5
    big = colors.clone()
    big[1] = torch.tensor([0.5, 0.5, 0.2])  # the big face (90%) changes by 0.3
    got = color_changes(torch.stack([small, big]), colors, vertices, faces)["color_change_p95"]
    assert got.tolist() == pytest.approx([0.5, 0.3], abs=1e-6)
    with pytest.raises(ValueError, match="colors"):
        color_changes(torch.zeros(3, 3), colors, vertices, faces)


def _ssim_by_hand(x: np.ndarray, y: np.ndarray) -> float:
    """SSIM of two 7 x 7 single-window grey images with scikit-image's constants (sample covariances)."""
    c1, c2 = (0.01 * 1.0) ** 2, (0.03 * 1.0) ** 2
    mx, my = x.mean(), y.mean()
    vx, vy = x.var(ddof=1), y.var(ddof=1)
    cov = ((x - mx) * (y - my)).sum() / (x.size - 1)
    return float((2 * mx * my + c1) * (2 * cov + c2) / ((mx**2 + my**2 + c1) * (vx + vy + c2)))


def test_render_ssim_matches_the_formula_on_one_window() -> None:
    generator = torch.Generator().manual_seed(3)
    grey = torch.rand(1, 1, 7, 7, generator=generator)
    other = (grey * 0.6 + 0.3 * torch.rand(1, 1, 7, 7, generator=generator)).clamp(0, 1)
    got = render_ssim(grey.expand(1, 3, 7, 7), other.expand(1, 3, 7, 7))
    want = _ssim_by_hand(grey[0, 0].double().numpy(), other[0, 0].double().numpy())
    assert float(got[0]) == pytest.approx(want, rel=1e-9)
    constant = render_ssim(torch.full((1, 3, 9, 9), 0.5), torch.full((1, 3, 9, 9), 0.25))
    assert float(constant[0]) == pytest.approx((2 * 0.5 * 0.25 + 1e-4) / (0.25 + 0.0625 + 1e-4), rel=1e-9)


def test_render_ssim_crops_to_the_objects_so_the_background_does_not_hide_a_change() -> None:
    benign = torch.ones(1, 3, 64, 64)
    benign[..., 28:36, 28:36] = 0.3  # a small grey object on white
    adversarial = benign.clone()
    adversarial[..., 28:36, 28:32] = 0.8  # half of it changes
    alpha = torch.zeros(1, 1, 64, 64)
    alpha[..., 28:36, 28:36] = 1.0
    whole = float(render_ssim(benign, adversarial)[0])
    cropped = float(render_ssim(benign, adversarial, alpha, alpha)[0])
    assert cropped < whole - 0.2
    same = render_ssim(benign, benign.clone(), alpha, alpha)
    assert float(same[0]) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="both"):
        render_ssim(benign, adversarial, alpha, None)
    with pytest.raises(ValueError, match="at least 7"):
        render_ssim(torch.ones(1, 3, 5, 5), torch.ones(1, 3, 5, 5))


def test_held_out_views_sit_between_and_away_from_the_attack_views() -> None:
    views = ViewSet.orbit([150.0, 165.0, 180.0, 195.0, 210.0], elevation=30.0, distance=2.5)
    held = held_out_views(views)
    assert held.camera.azimuth is not None and held.camera.elevation is not None
    assert held.camera.azimuth.tolist() == pytest.approx([157.5, 172.5, 187.5, 202.5, 120.0, 240.0, 180.0, 180.0])
    assert held.camera.elevation.tolist() == pytest.approx([30.0] * 6 + [50.0, 10.0])
    assert held.camera.distance is not None and held.camera.distance.tolist() == pytest.approx([2.5] * 8)
    one = held_out_views(ViewSet.orbit([90.0], elevation=70.0))
    assert len(one) == 4 and one.camera.elevation is not None
    assert one.camera.elevation.tolist() == pytest.approx([70.0, 70.0, 80.0, 50.0])  # elevation kept below 80


def test_held_out_views_of_a_look_at_camera_keep_its_distance_to_the_target() -> None:
    camera = Camera.look_at([0.0, 1.0, 4.0], [0.0, 1.0, 0.0], [0.0, 1.0, 0.0])
    held = held_out_views(ViewSet(camera, Lights.default(camera)))
    assert len(held) == 4 and held.camera.eye_position is not None
    offsets = held.camera.eye_position - torch.tensor([0.0, 1.0, 0.0])
    assert offsets.norm(dim=1).tolist() == pytest.approx([4.0] * 4, rel=1e-5)
    # turned left and right about up by 30 degrees: x = -/+ 4 sin 30
    assert sorted(offsets[:2, 0].tolist()) == pytest.approx([-2.0, 2.0], abs=1e-5)


@needs_native
def test_perceptibility_measures_of_a_scaled_mesh() -> None:
    from meshadv.mesh import builtin_mesh

    mesh = builtin_mesh("chair")
    grown = mesh.with_vertices(mesh.vertices * 1.2)
    views = ViewSet.orbit([30.0, 60.0], elevation=20.0, distance=2.8)
    same, scaled = perceptibility_measures(mesh, [mesh, grown], views, RenderSetup(image_size=64))
    assert same["max_displacement"] == 0.0 and same["ssim_held_out_min"] == pytest.approx(1.0)
    norms = mesh.vertices.norm(dim=1)
    assert scaled["max_displacement"] == pytest.approx(0.2 * float(norms.max()) / mesh.bbox_diagonal(), rel=1e-5)
    assert scaled["normal_change_p95_deg"] == pytest.approx(0.0, abs=1e-2)
    assert same["edge_strain_p95"] == 0.0 and scaled["edge_strain_p95"] == pytest.approx(0.2, rel=1e-4)
    assert scaled["ssim_held_out_min"] < scaled["ssim_held_out_mean"] < 1.0
    with pytest.raises(ValueError, match="topology"):
        perceptibility_measures(mesh, [builtin_mesh("sphere")], views, RenderSetup(image_size=64))


@needs_native
def test_an_attack_result_reports_the_measures_in_json_summary_and_footer() -> None:
    from stand_in_victims import PooledLinearClassifier

    from meshadv.attacks import ShapeAttack, TargetedMisclassification
    from meshadv.commands._comparison import distortion_line
    from meshadv.mesh import builtin_mesh

    attack = ShapeAttack(method="ddn", steps=8, method_options={"step_size": 3e-2, "final_step_size": 3e-3,
                                                                 "init_budget": 1e-2})
    result = attack(builtin_mesh("chair"), ViewSet.orbit([40.0], elevation=20.0, distance=2.6),
                    PooledLinearClassifier(), TargetedMisclassification(728), setup=RenderSetup(image_size=48))
    record = result.to_record()["distances"][0]
    for key in ("max_displacement", "p95_displacement", "normal_change_mean_deg", "normal_change_p95_deg",
                "edge_strain_p95", "color_change_p95", "ssim_held_out_mean", "ssim_held_out_min",
                "laplacian_pair_mean"):
        assert record[key] is not None, key
    mesh = builtin_mesh("chair")
    want = surface_measures(result.mesh.vertices, result.mesh.face_colors, mesh.vertices, mesh.face_colors,
                            mesh.faces)
    assert record["normal_change_p95_deg"] == pytest.approx(want["normal_change_p95_deg"], rel=1e-5)
    assert record["edge_strain_p95"] == pytest.approx(want["edge_strain_p95"], rel=1e-5)
    assert record["max_displacement"] > 0 and record["ssim_held_out_min"] < 1.0
    summary = result.summary()
    assert f"p95 {100 * record['p95_displacement']:.3g}%" in summary
    assert f"SSIM held-out mean {record['ssim_held_out_mean']:.3g}" in summary
    assert f"edge strain p95 {record['edge_strain_p95']:.3g}" in summary
    footer = distortion_line(record, "shape")
    assert "95th percentile" in footer and "face normals turn" in footer and "SSIM" in footer
    assert f"edge length stretched or squeezed by at most {100 * record['edge_strain_p95']:.2g}%" in footer


def test_sweep_tables_get_rows_for_the_measures_records_hold() -> None:
    from meshadv.experiments.tables import attack_rows, table1

    mesh = {"source": "pascal3d", "path": "pascal3d/chair/01.ply", "class": "chair"}
    spec = {"kind": "single", "mesh": mesh, "config_index": 0, "seed": 0, "victim": "v", "perturbation": "shape",
            "source_class": "chair", "target": "sofa"}
    measures = {"laplacian_sum": 0.25, "laplacian_pair_mean": 0.01, "color_rmse": 0.0, "max_displacement": 0.03,
                "p95_displacement": 0.01, "normal_change_mean_deg": 2.0, "normal_change_p95_deg": 9.0,
                "edge_strain_p95": 0.03, "dssim_held_out_max": 0.04}
    rows = attack_rows([{"spec": spec, "record": {"success": True, "distances": measures}}])
    assert {r.measure: r.distance for r in rows} == {k: v for k, v in measures.items() if k != "color_rmse"}
    by_name = {r.distance_name: r for r in table1(rows)}
    assert by_name["normal_change_p95_deg"].worst.distance == pytest.approx(9.0)
    assert by_name["edge_strain_p95"].worst.distance == pytest.approx(0.03)
    assert not by_name["max_displacement"].paper_measure
    old = attack_rows([{"spec": spec, "record": {"success": True, "distances": {"laplacian_sum": 0.25,
                                                                                 "laplacian_pair_mean": 0.01}}}])
    assert [r.measure for r in old] == ["laplacian_pair_mean", "laplacian_sum"]  # no empty rows for older records


def test_texel_changes_is_the_95th_percentile_over_texels() -> None:
    from meshadv.perceptibility.geometry import texel_changes

    texture = torch.zeros(4, 5, 3)
    adversarial = texture.clone()
    adversarial[0, :4] = 0.1  # 4 of 20 texels (more than 5%) move by 0.1 * sqrt(3): the 95th percentile
    assert float(texel_changes(adversarial, texture)["color_change_p95"][0]) == pytest.approx(0.1 * math.sqrt(3))
    adversarial[1:, :] = 0.0
    adversarial[0, :] = 0.0
    adversarial[0, 0] = 1.0  # one texel of 20 (5%) changes: the 95th percentile stays 0
    assert float(texel_changes(adversarial, texture)["color_change_p95"][0]) == 0.0
    with pytest.raises(ValueError, match="texture"):
        texel_changes(torch.zeros(2, 4, 4, 3), texture)


def test_the_step_cap_of_a_texture_image_needs_the_pristine_texture() -> None:
    from meshadv.perceptibility.cap import PerceptibilityCap, step_measures
    from meshadv.render.surface_reflectance import SurfaceReflectance

    vertices = torch.tensor([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    faces = torch.tensor([[0, 1, 2]])
    uvs = torch.tensor([[0.0, 0], [1, 0], [0, 1]])
    texture = torch.zeros(2, 2, 3)
    adversarial = SurfaceReflectance(torch.full((1, 2, 2, 3), 0.2), uvs, faces)
    cap = PerceptibilityCap(max_displacement=None, normal_change_p95_deg=None, color_change_p95=0.05)
    measured = step_measures(cap, vertices[None], adversarial, vertices, torch.zeros(1, 3), faces, texture=texture)
    assert float(measured["color_change_p95"][0]) == pytest.approx(0.2 * math.sqrt(3))
    assert not bool(cap.admits(measured))
    with pytest.raises(ValueError, match="pristine texture"):
        step_measures(cap, vertices[None], adversarial, vertices, torch.zeros(1, 3), faces)
