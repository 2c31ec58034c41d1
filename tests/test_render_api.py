"""The public surface of ``meshadv.render``: exports, docstrings and type annotations."""

from __future__ import annotations

import inspect

import meshadv.render as render_pkg


def public_callables() -> list[tuple[str, object]]:
    items = []
    for name in render_pkg.__all__:
        obj = getattr(render_pkg, name)
        items.append((name, obj))
        if inspect.isclass(obj):
            for attr, member in vars(obj).items():
                if attr.startswith("_"):
                    continue
                func = member.__func__ if isinstance(member, (classmethod, staticmethod)) else member
                if inspect.isfunction(func):
                    items.append((f"{name}.{attr}", func))
    return items


def test_every_public_item_has_a_docstring() -> None:
    missing = [name for name, obj in public_callables() if not (inspect.getdoc(obj) or "").strip()]
    assert not missing, f"missing docstrings: {missing}"


def test_every_public_function_is_annotated() -> None:
    missing = []
    for name, obj in public_callables():
        if not inspect.isfunction(obj):
            continue
        sig = inspect.signature(obj)
        for pname, param in sig.parameters.items():
            if pname in ("self", "cls") or param.kind in (param.VAR_POSITIONAL, param.VAR_KEYWORD):
                continue
            if param.annotation is inspect.Parameter.empty:
                missing.append(f"{name}({pname})")
        if sig.return_annotation is inspect.Signature.empty:
            missing.append(f"{name} -> ?")
    assert not missing, f"missing annotations: {missing}"
