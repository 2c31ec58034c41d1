"""A finished attack's perturbation, kept compact in the results database so that a copy of the database alone
gives back the adversarial mesh the tables counted.

A shape attack moves vertices, a texture attack changes face colours: the perturbation is the difference between the
adversarial and the benign mesh in the fields that changed, stored as float16 and compressed (zlib). Applying it to
the job's benign mesh (loaded again from its spec, :func:`meshadv.experiments.jobs.load_job_mesh`) rebuilds the
adversarial mesh to float16 rounding of the difference (a relative 2**-11 of each change): far below the attacks' own
scales (a shape flow of 1e-3..1e-1 of the unit-sized mesh, a colour change against 8-bit colour steps of 1/255).

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
FIELDS = ("vertices", "face_colors")
#: The key of a job record that carries its perturbation (:meth:`Perturbation.to_record`) to the results database,
#: which keeps it in its own table (:meth:`meshadv.experiments.ResultStore.mark_done`), not in the record.
PERTURBATION_KEY = "perturbation"


@dataclass(frozen=True)
class Perturbation:
    """The change an attack made to a mesh's vertices and/or face colours, compressed.

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
        """The fields joined by ``+`` (``"vertices"``, ``"face_colors"`` or ``"vertices+face_colors"``)."""
        return "+".join(self.fields)

    @classmethod
    def from_kind(cls, kind: str, data: bytes) -> "Perturbation":
        """The perturbation of :attr:`kind` ``kind`` holding ``data``."""
        return cls(tuple(str(kind).split("+")), bytes(data))

    @classmethod
    def between(cls, benign: Any, adversarial: Any) -> "Perturbation":
        """The perturbation taking ``benign`` to ``adversarial`` (two :class:`~meshadv.mesh.Mesh` of one topology): the
        fields that differ (the vertices alone when neither does).

        Raises:
            ValueError: the meshes do not share their topology, or a difference overflows float16.
        """
        import torch

        if benign.vertices.shape != adversarial.vertices.shape or not torch.equal(benign.faces.cpu(),
                                                                                  adversarial.faces.cpu()):
            raise ValueError("benign and adversarial meshes must have the same number of vertices and the same faces")
        deltas = {name: (getattr(adversarial, name).detach().double() - getattr(benign, name).detach().double())
                  .cpu().numpy() for name in FIELDS}
        fields = tuple(name for name in FIELDS if np.any(deltas[name] != 0)) or ("vertices",)
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
            ValueError: ``benign`` is not the mesh the perturbation was made on (other sizes), or a face-colour
                perturbation of a ``SurfaceMesh`` (a shape job's is its vertices).
        """
        import torch

        from meshadv.mesh.surface_mesh import SurfaceMesh

        rows = {"vertices": benign.num_vertices, "face_colors": benign.num_faces}
        surface = isinstance(benign, SurfaceMesh)
        mesh = benign if surface else benign.detach()
        for name, delta in self.deltas(rows).items():
            if surface and name != "vertices":
                raise ValueError(f"a textured or vertex-coloured mesh takes a vertex perturbation, got {name}")
            field = getattr(mesh, name).detach()
            changed = (field + torch.as_tensor(delta, device=field.device)).contiguous()
            mesh = mesh.with_vertices(changed) if name == "vertices" else mesh.with_face_colors(changed)
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
