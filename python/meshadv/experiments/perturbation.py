"""A finished attack's perturbation, kept compact in the results database so that a copy of the database alone
gives back the adversarial mesh the tables counted.

A shape attack moves vertices, a texture attack changes face colours, a texture-map attack the texels of a textured
mesh's image (``texture``, its ``(Ht * Wt, 3)`` rows): the perturbation is the difference between the adversarial and
the benign mesh in the fields that changed, stored as float16 and compressed (zlib). A textured or vertex-coloured
mesh (:class:`~meshadv.mesh.surface_mesh.SurfaceMesh`) keeps its vertices and texture; its face colours follow them.
Applying it to the job's benign mesh (loaded again from its spec, :func:`meshadv.experiments.jobs.load_job_mesh`)
rebuilds the adversarial mesh to float16 rounding of the difference (a relative 2**-11 of each change): far below the
attacks' own scales (a shape flow of 1e-3..1e-1 of the unit-sized mesh, a colour change against 8-bit colour steps
of 1/255).

Example:
    >>> packed = Perturbation.between(benign, adversarial)   # doctest: +SKIP
    >>> again = packed.apply(benign)                        # doctest: +SKIP
"""

from __future__ import annotations

import base64
import binascii
import zlib
from dataclasses import dataclass
from typing import Any, Dict, Tuple

import numpy as np

__all__ = ["Perturbation", "FIELDS", "PERTURBATION_KEY"]

#: The mesh fields a perturbation may change, in the order their differences are stored.
FIELDS = ("vertices", "face_colors", "texture")
#: The key of a job record that carries its perturbation (:meth:`Perturbation.to_record`) to the results database,
#: which keeps it in its own table (:meth:`meshadv.experiments.ResultStore.mark_done`), not in the record.
PERTURBATION_KEY = "perturbation"


@dataclass(frozen=True)
class Perturbation:
    """The change an attack made to a mesh's vertices, face colours and/or texture, compressed.

    Attributes:
        fields: the changed fields, a non-empty ordered subset of :data:`FIELDS`.
        data: zlib-compressed little-endian float16 differences, each field's ``(rows, 3)`` row-major, in order.
    """

    fields: Tuple[str, ...]
    data: bytes

    def __post_init__(self) -> None:
        if not self.fields or tuple(f for f in FIELDS if f in self.fields) != tuple(self.fields):
            raise ValueError(f"fields must be a non-empty ordered subset of {FIELDS}, got {self.fields!r}")

    @property
    def kind(self) -> str:
        """The fields joined by ``+`` (``"vertices"``, ``"face_colors"``, ``"texture"``, ``"vertices+face_colors"``,
        ...)."""
        return "+".join(self.fields)

    @classmethod
    def from_kind(cls, kind: str, data: bytes) -> "Perturbation":
        """The perturbation of :attr:`kind` ``kind`` holding ``data``."""
        return cls(tuple(str(kind).split("+")), bytes(data))

    @classmethod
    def between(cls, benign: Any, adversarial: Any) -> "Perturbation":
        """The perturbation taking ``benign`` to ``adversarial`` (two :class:`~meshadv.mesh.Mesh` or two
        ``SurfaceMesh`` of one topology, and one texture size): the fields that differ (the vertices alone when none
        does).

        Raises:
            ValueError: the meshes do not share their topology or texture size, or a difference overflows float16.
        """
        import torch

        if benign.vertices.shape != adversarial.vertices.shape or not torch.equal(benign.faces.cpu(),
                                                                                  adversarial.faces.cpu()):
            raise ValueError("benign and adversarial meshes must have the same number of vertices and the same faces")
        names = _fields_of(benign)
        if "texture" in names and tuple(benign.texture.shape) != tuple(getattr(adversarial, "texture").shape):
            raise ValueError("benign and adversarial meshes must have textures of the same size")
        deltas = {name: (getattr(adversarial, name).detach().double() - getattr(benign, name).detach().double())
                  .cpu().numpy().reshape(-1, 3) for name in names}
        fields = tuple(name for name in names if np.any(deltas[name] != 0)) or ("vertices",)
        halves = [deltas[name].astype("<f2") for name in fields]
        for name, half in zip(fields, halves):
            if not np.isfinite(half).all():
                raise ValueError(f"the {name} perturbation does not fit float16 "
                                 f"(largest change {np.abs(deltas[name]).max()})")
        return cls(fields, zlib.compress(b"".join(h.tobytes() for h in halves), 9))

    def deltas(self, rows: Dict[str, int]) -> Dict[str, np.ndarray]:
        """The float32 ``(rows[field], 3)`` differences of each field.

        Raises:
            ValueError: the data does not hold that many values (a perturbation of another mesh).
        """
        raw = np.frombuffer(zlib.decompress(self.data), dtype="<f2")
        want = sum(3 * rows[name] for name in self.fields)
        if raw.size != want:
            raise ValueError(f"the perturbation holds {raw.size} values, the mesh's {self.kind} {want}: it was made "
                             "on another mesh")
        out, start = {}, 0
        for name in self.fields:
            n = 3 * rows[name]
            out[name] = raw[start:start + n].astype(np.float32).reshape(rows[name], 3)
            start += n
        return out

    def apply(self, benign: Any) -> Any:
        """The adversarial mesh: ``benign`` with the differences added to its fields.

        Raises:
            ValueError: ``benign`` is not the mesh the perturbation was made on (other sizes), or does not keep a
                field it changes (face colours of a ``SurfaceMesh``, a texture of a mesh without one).
        """
        import torch

        from meshadv.mesh.surface_mesh import SurfaceMesh

        names = _fields_of(benign)
        texture = getattr(benign, "texture", None)
        rows = {"vertices": benign.num_vertices, "face_colors": benign.num_faces,
                "texture": 0 if texture is None else texture.shape[0] * texture.shape[1]}
        unknown = [name for name in self.fields if name not in names]
        if unknown:
            raise ValueError(f"the perturbation changes {unknown}, which this mesh does not keep (it takes "
                             f"{list(names)})")
        mesh = benign if isinstance(benign, SurfaceMesh) else benign.detach()
        for name, delta in self.deltas(rows).items():
            field = getattr(mesh, name).detach()
            changed = (field + torch.as_tensor(delta, device=field.device).reshape(field.shape)).contiguous()
            if name == "vertices":
                mesh = mesh.with_vertices(changed)
            elif name == "texture":
                mesh = mesh.with_texture(changed)
            else:
                mesh = mesh.with_face_colors(changed)
        return mesh

    def to_record(self) -> Dict[str, Any]:
        """A JSON-able dict (the data in base64) that :meth:`from_record` reads back."""
        return {"kind": self.kind, "data": base64.b64encode(self.data).decode("ascii")}

    @classmethod
    def from_record(cls, record: Dict[str, Any]) -> "Perturbation":
        """Rebuild a perturbation written by :meth:`to_record`.

        Raises:
            ValueError: missing keys or bad values.
        """
        try:
            return cls.from_kind(str(record["kind"]), base64.b64decode(str(record["data"]), validate=True))
        except (KeyError, TypeError, binascii.Error) as err:
            raise ValueError(f"a perturbation record needs kind and base64 data, got {record!r:.80}") from err


def _fields_of(mesh: Any) -> Tuple[str, ...]:
    """The fields of :data:`FIELDS` a perturbation of ``mesh`` may change: a ``SurfaceMesh``'s vertices and texture
    (its face colours follow them), a per-face mesh's vertices and face colours."""
    from meshadv.mesh.surface_mesh import SurfaceMesh

    if not isinstance(mesh, SurfaceMesh):
        return ("vertices", "face_colors")
    return ("vertices", "texture") if mesh.texture is not None else ("vertices",)
