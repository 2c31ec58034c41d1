"""One labelled comparison image of an attack: benign | adversarial side by side, one row per view.

Each render is scaled up (nearest neighbour) to at least :data:`MIN_CELL` pixels and captioned with the victim's
top-1 class and its confidence; a footer gives the held-out verdict and the distortion numbers. Written by
``meshadv demo`` and ``meshadv attack`` as ``comparison.png``.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, List, Optional, Sequence, Tuple, Union

__all__ = ["MIN_CELL", "captions_for", "comparison_image", "distortion_line", "held_out_line", "save_comparison",
           "status_words", "top1_captions", "write_attack_outputs"]

#: Smallest side, in pixels, of one render in the comparison image.
MIN_CELL = 320
_PAD = 8


def _font(size: int) -> Any:
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except (TypeError, OSError):  # Pillow < 10.1 or no FreeType: the small bitmap font
        return ImageFont.load_default()


def _to_pil(image: Any, side: int) -> Any:
    from PIL import Image

    array = (image.detach().float().clamp(0, 1).permute(1, 2, 0).cpu().numpy() * 255).round().astype("uint8")
    pil = Image.fromarray(array)
    scale = max(1, math.ceil(side / max(pil.size)))
    return pil.resize((pil.width * scale, pil.height * scale), Image.NEAREST)


def top1_captions(logits: Any, names: Sequence[str]) -> List[str]:
    """``"name 0.62"`` (top-1 class and softmax probability) for each row of ``(V, C)`` logits."""
    import torch

    probs = torch.softmax(logits.detach().float(), dim=1)
    values, idx = probs.max(dim=1)
    return [f"{names[int(i)] if int(i) < len(names) else int(i)} {float(v):.2f}" for v, i in zip(values, idx)]


def distortion_line(distances: dict, perturbation: str) -> str:
    """A one-line summary of an attack's distortion (``AttackResult.distances[t]``)."""
    def pick(*keys: str) -> Optional[float]:
        for key in keys:
            if distances.get(key) is not None:
                return float(distances[key])
        return None

    if perturbation == "texture-map":
        rmse, tv = pick("texel_rmse"), pick("texture_tv")
        return ("texture image change: texel RMSE " + ("-" if rmse is None else f"{rmse:.4f}") + ", UV total "
                "variation " + ("-" if tv is None else f"{tv:.4f}"))
    seen = []
    ssim_mean, ssim_min = pick("ssim_held_out_mean"), pick("ssim_held_out_min")
    if ssim_mean is not None and ssim_min is not None:
        seen.append(f"SSIM of benign vs adversarial renders on held-out views: mean {ssim_mean:.3f}, "
                    f"lowest {ssim_min:.3f}")
    if perturbation == "texture":
        rmse, p95 = pick("color_rmse"), pick("color_change_p95")
        parts = ["colour RMSE " + ("-" if rmse is None else f"{rmse:.4f}")]
        if p95 is not None:
            parts.append(f"95% of the area changes colour by at most {p95:.3f}")
        return "texture change: " + ", ".join(parts + seen)
    parts = []
    disp, p95 = pick("max_displacement"), pick("p95_displacement")
    if disp is not None:
        parts.append(f"largest vertex move {100 * disp:.2g}% of the bounding-box diagonal"
                     + ("" if p95 is None else f" (95th percentile {100 * p95:.2g}%)"))
    turn_mean, turn_p95 = pick("normal_change_mean_deg"), pick("normal_change_p95_deg")
    if turn_mean is not None and turn_p95 is not None:
        parts.append(f"face normals turn {turn_mean:.2g} deg on average, 95% of the area by at most {turn_p95:.2g} "
                     "deg")
    strain, strain_max = pick("edge_strain_p95"), pick("edge_strain_max")
    if strain is not None:
        parts.append(f"95% of the edge length stretched or squeezed by at most {100 * strain:.2g}%"
                     + ("" if strain_max is None else f" (any edge by at most {100 * strain_max:.3g}%)"))
    parts += seen
    pair_mean, eq4_sum = pick("laplacian_pair_mean"), pick("laplacian_sum")
    if pair_mean is not None:
        parts.append(f"Laplacian pair mean {pair_mean:.3g} (the paper's measure)")
    if eq4_sum is not None:
        parts.append(f"Eq. 4 sum {eq4_sum:.3g}")
    return "shape change: " + (", ".join(parts) if parts else "-")


def held_out_line(result: Any, target: int = 0) -> Optional[str]:
    """The held-out verdict of target ``target`` of an ``AttackResult`` in words, or ``None`` without held-out views:
    ``"held-out views (never optimised on): the target holds on 4/5 (80%); SUCCESS needs >= 80%"``."""
    from meshadv.attacks.result import held_out_sentence

    if result.eval_success is None:
        return None
    return held_out_sentence(int(result.eval_success[target].sum()), int(result.eval_success.shape[1]),
                             result.held_out_fraction)


def status_words(result: Any, target: int = 0) -> str:
    """The verdict of target ``target`` of an ``AttackResult`` for a title: ``"succeeded"``, ``"held on the attack
    views, not on the held-out views"`` (the held-out views alone failed it) or ``"did not succeed"``."""
    from meshadv.attacks.result import enough_views

    if bool(result.succeeded[target]):
        return "succeeded"
    views_hold = bool(enough_views(result.success_rate[target], result.success_fraction))
    if views_hold and bool(result.inside_cap[target]) and not bool(result.holds_held_out[target]):
        return "held on the attack views, not on the held-out views"
    return "did not succeed"


def comparison_image(before: Any, after: Any, before_captions: Sequence[str], after_captions: Sequence[str],
                     footer: Union[str, Sequence[str]], title: str = "") -> Any:
    """The labelled side-by-side image (a PIL image).

    Args:
        before: ``(V, 3, H, W)`` benign renders in ``[0, 1]``.
        after: ``(V, 3, H, W)`` adversarial renders.
        before_captions: ``V`` captions (e.g. the top-1 and its confidence) of the benign renders.
        after_captions: ``V`` captions of the adversarial renders.
        footer: text under the image (the distortion numbers), or several paragraphs, each wrapped to the width.
        title: text above the image (wrapped to its width).

    Returns:
        An RGB ``PIL.Image``.

    Raises:
        ValueError: the numbers of renders and captions disagree.
    """
    from PIL import Image, ImageDraw

    views = len(before)
    if len(after) != views or len(before_captions) != views or len(after_captions) != views:
        raise ValueError(f"before/after renders and captions must all have {views} entries")
    cells = [(_to_pil(b, MIN_CELL), _to_pil(a, MIN_CELL)) for b, a in zip(before, after)]
    cell_w = max(c.width for pair in cells for c in pair)
    cell_h = max(c.height for pair in cells for c in pair)
    font, small = _font(20), _font(16)
    line = 26
    width = 2 * cell_w + 3 * _PAD
    title_lines = _wrapped(title, font, width - 2 * _PAD) if title else []
    header = line * (len(title_lines) + 1)
    paragraphs = [footer] if isinstance(footer, str) else list(footer)
    footer_lines = [row for text in paragraphs for row in _wrapped(text, small, width - 2 * _PAD)]
    height = header + views * (cell_h + line + _PAD) + line * len(footer_lines) + _PAD
    canvas = Image.new("RGB", (width, height), "white")
    draw = ImageDraw.Draw(canvas)
    for i, text in enumerate(title_lines):
        draw.text((_PAD, 2 + i * line), text, fill="black", font=font)
    for col, name in enumerate(("benign", "adversarial")):
        draw.text((_PAD + col * (cell_w + _PAD), header - line + 2), name, fill="black", font=font)
    y = header
    for (b, a), cb, ca in zip(cells, before_captions, after_captions):
        for col, (img, caption) in enumerate(((b, cb), (a, ca))):
            x = _PAD + col * (cell_w + _PAD)
            canvas.paste(img, (x, y))
            draw.text((x, y + cell_h + 2), f"top-1: {caption}", fill=(150, 0, 0) if col else "black", font=small)
        y += cell_h + line + _PAD
    for text in footer_lines:
        draw.text((_PAD, y), text, fill="black", font=small)
        y += line
    return canvas


def _wrapped(text: str, font: Any, width: int) -> List[str]:
    """``text`` broken at spaces into lines no wider than ``width`` pixels in ``font`` (a word longer than that
    gets a line of its own)."""
    lines: List[str] = []
    for word in text.split(" "):
        if lines and font.getlength(f"{lines[-1]} {word}") <= width:
            lines[-1] = f"{lines[-1]} {word}"
        else:
            lines.append(word)
    return lines or [""]


def save_comparison(image: Any, path: Union[str, Path]) -> Path:
    """Write ``image`` (PIL) as a PNG atomically (``meshadv.util.atomic``: usual permissions, never half-written)."""
    from meshadv.util.atomic import atomic_path

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path, suffix=".png") as tmp:
        image.save(tmp, format="PNG")
    return path


def captions_for(victim: Any, images: Any) -> Tuple[List[str], Any]:
    """Top-1 captions of ``victim`` on ``images`` (classifiers; detectors get their best detection)."""
    import torch

    with torch.no_grad():
        if getattr(victim, "kind", "classifier") == "classifier":
            logits = victim(images)
            return top1_captions(logits, list(victim.class_names)), logits
        captions = []
        for det in victim.detect(images):
            records = sorted(det.to_records(), key=lambda r: -r["score"])
            captions.append(f"{records[0]['label']} {records[0]['score']:.2f}" if records else "nothing detected")
        return captions, None


def write_attack_outputs(result: Any, victim: Any, output: Path, loaded: Any, title: str, *,
                         source_class: Optional[str] = None) -> Path:
    """What ``meshadv attack`` and ``meshadv demo`` add to ``AttackResult.save``: ``comparison.png`` (its footer
    the held-out verdict, :func:`held_out_line`, and the distortion numbers), the
    adversarial mesh in the input file's frame, the benign (attacked, normalised) mesh as ``benign.ply`` (and as
    ``benign.obj`` with its texture or vertex colours), and the input (path, Z-up, transform, the source class) in
    ``result.json``.

    Args:
        result: the saved ``AttackResult`` (its folder is ``output``).
        victim: the victim (captions of the comparison image).
        output: the result folder.
        loaded: the ``MeshInput`` the attack started from.
        title: the comparison image's title line.
        source_class: the class the benign mesh is (what the benign check checked; ``meshadv transfer attack``
            judges untargeted transfer against it), or ``None`` when unknown.

    Returns:
        The comparison image's path.
    """
    import json

    from meshadv.mesh import save_mesh
    from meshadv.mesh.surface_mesh import SurfaceMesh, save_surface_mesh
    from meshadv.util.atomic import write_json_atomic

    before, _ = captions_for(victim, result.original_images)
    after, _ = captions_for(victim, result.images[0])
    held = held_out_line(result)
    footer = [distortion_line(result.distances[0], result.perturbation)]
    image = comparison_image(result.original_images, result.images[0], before, after,
                             footer=footer if held is None else [held, *footer], title=title)
    path = save_comparison(image, output / "comparison.png")
    record = json.loads((output / "result.json").read_text(encoding="utf-8"))
    entry = {"mesh": loaded.label, "path": None if loaded.path is None else str(loaded.path), "z_up": loaded.z_up,
             "normalize_transform": None if loaded.transform is None else loaded.transform.to_dict(),
             "source_class": source_class, "input_frame_meshes": []}
    if loaded.transform is not None:
        for t, mesh in enumerate(result.adversarial):
            stem = "adversarial" if len(result.adversarial) == 1 else f"adversarial_t{t}"
            if isinstance(mesh, SurfaceMesh):  # OBJ + MTL + texture PNG, or OBJ with vertex colours
                name = f"{stem}_input_frame.obj"
                save_surface_mesh(mesh.to_original(loaded.transform), output / name)
            else:
                name = f"{stem}_input_frame.ply"
                detached = mesh.detach()
                save_mesh(detached.with_vertices(loaded.transform.to_original(detached.vertices)), output / name)
            entry["input_frame_meshes"].append(name)
    benign = getattr(result.original, "mesh", result.original)  # a textured mesh's geometry and face colours
    save_mesh(benign.detach(), output / "benign.ply")  # the benign control of `meshadv transfer attack`
    entry["benign_mesh"] = "benign.ply"
    if isinstance(result.original, SurfaceMesh):  # with its texture or vertex colours, as the attack drew it
        save_surface_mesh(result.original, output / "benign.obj")
        entry["benign_mesh"] = "benign.obj"
    record["input"] = entry
    write_json_atomic(record, output / "result.json")
    return path
