"""A Mitsuba 3 texture that is the product of two textures (``meshadv_product``), registered from Python: what a mesh
with both a texture and vertex colours reflects (a ``bitmap`` times a ``vertex_color`` ``mesh_attribute``), which no
built-in Mitsuba plugin computes. Runs in the rendering child process; only :func:`product_texture` needs Mitsuba
(passed in as ``mi``).
"""

from __future__ import annotations

from typing import Any

__all__ = ["PRODUCT_PLUGIN", "product_texture"]

#: The plugin name the product texture is registered under.
PRODUCT_PLUGIN = "meshadv_product"

#: Variants the plugin is registered for in this process (registration is per variant).
_REGISTERED: set[str] = set()


def _register(mi: Any) -> None:
    """Register :data:`PRODUCT_PLUGIN` for the current variant (once per variant and process)."""
    variant = mi.variant()
    if variant in _REGISTERED:
        return

    class ProductTexture(mi.Texture):  # type: ignore[name-defined, misc]
        """``first(si) * second(si)``, for spectra (``eval``) and scalars (``eval_1``)."""

        def __init__(self, props: Any) -> None:
            mi.Texture.__init__(self, props)
            self.first = props["first"]
            self.second = props["second"]

        def eval(self, si: Any, active: Any = True) -> Any:
            return self.first.eval(si, active) * self.second.eval(si, active)

        def eval_1(self, si: Any, active: Any = True) -> Any:
            return self.first.eval_1(si, active) * self.second.eval_1(si, active)

        def mean(self) -> Any:  # exact for independent factors only; Mitsuba uses it for heuristics
            return self.first.mean() * self.second.mean()

        def traverse(self, callback: Any) -> None:
            callback.put("first", self.first, mi.ParamFlags.NonDifferentiable)
            callback.put("second", self.second, mi.ParamFlags.NonDifferentiable)

    mi.register_texture(PRODUCT_PLUGIN, lambda props: ProductTexture(props))
    _REGISTERED.add(variant)


def product_texture(mi: Any, first: dict[str, Any], second: dict[str, Any]) -> dict[str, Any]:
    """The scene-dict entry of the texture ``first * second`` (two texture dicts), registering the plugin for the
    current variant on first use.

    Example:
        >>> reflectance = product_texture(mi, {"type": "bitmap", ...},  # doctest: +SKIP
        ...                               {"type": "mesh_attribute", "name": "vertex_color"})
    """
    _register(mi)
    return {"type": PRODUCT_PLUGIN, "first": first, "second": second}
