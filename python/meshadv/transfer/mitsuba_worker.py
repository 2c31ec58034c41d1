"""Child-process entry point that renders pickled :class:`~meshadv.transfer.mitsuba_spec.SceneSpec` objects with
Mitsuba.

Run as ``python -m meshadv.transfer.mitsuba_worker IN.pkl OUT.npz VARIANT``. It imports only numpy and mitsuba (never
torch), so it starts quickly; if Mitsuba aborts, only this process dies. See :mod:`meshadv.transfer.mitsuba_process`.
"""

from __future__ import annotations

import os
import pickle
import sys

import numpy as np

from meshadv.util.atomic import atomic_path


def main(argv: list[str]) -> int:
    """Render every spec of ``argv[0]`` (a pickled list) with variant ``argv[2]`` into the npz ``argv[1]``."""
    in_path, out_path, variant = argv[0], argv[1], argv[2]
    import mitsuba as mi

    mi.set_variant(variant)
    threads = os.environ.get("MESHADV_MITSUBA_THREADS")
    if threads:
        import drjit as dr

        dr.set_thread_count(int(threads))
    from meshadv.transfer.mitsuba_scene import build_mitsuba_scene

    with open(in_path, "rb") as fh:
        specs = pickle.load(fh)
    arrays = {}
    for i, spec in enumerate(specs):
        scene = build_mitsuba_scene(mi, spec)
        rgba = np.array(mi.render(scene, seed=int(spec.seed)), dtype=np.float32)
        rgba = rgba[:, ::-1]  # Mitsuba's camera is physical, NMR's image is its mirror (see mitsuba_scene)
        rgb, alpha = rgba[..., :3], np.clip(rgba[..., 3], 0.0, 1.0)
        if spec.background is not None and not spec.mask:
            rgb = rgb + (1.0 - alpha)[..., None] * np.asarray(spec.background, dtype=np.float32)
        arrays[f"image_{i}"] = np.clip(np.nan_to_num(rgb), 0.0, 1.0).astype(np.float32)
        arrays[f"alpha_{i}"] = alpha.astype(np.float32)
    with atomic_path(out_path, suffix=".npz") as tmp:
        np.savez(tmp, **arrays)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
