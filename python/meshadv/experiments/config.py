"""The declarative sweep file (TOML or YAML) and its expansion into attack jobs: the import path callers use.

The work is done in three modules with one job each, re-exported here:

- :mod:`~meshadv.experiments.sweep_file`: the file's sections, reading and checking them (:class:`SweepConfig`,
  :func:`parse_config`, :func:`load_config`);
- :mod:`~meshadv.experiments.sweep_views`: the views a sweep attacks from (:func:`view_record`,
  :func:`rendering_configurations`, the multi-view sets);
- :mod:`~meshadv.experiments.job_expansion`: the job specs and their order (:func:`expand_jobs`,
  :func:`rendering_set_instances`, :func:`job_part`, :func:`select_parts`, :func:`select_where`).

Example:
    >>> jobs = expand_jobs(load_config("configs/paper_small.toml"))  # doctest: +SKIP
"""

from __future__ import annotations

from meshadv.experiments.job_expansion import (
    expand_jobs,
    job_part,
    parse_where,
    rendering_set_instances,
    select_parts,
    select_where,
)
from meshadv.experiments.sweep_file import DEFAULT_JOB, PASCAL3D_CLASSES, SweepConfig, load_config, parse_config
from meshadv.experiments.sweep_views import rendering_configurations, view_record

__all__ = [
    "SweepConfig",
    "load_config",
    "parse_config",
    "expand_jobs",
    "job_part",
    "parse_where",
    "select_parts",
    "select_where",
    "view_record",
    "PASCAL3D_CLASSES",
    "DEFAULT_JOB",
    "rendering_configurations",
    "rendering_set_instances",
]
