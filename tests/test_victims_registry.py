"""Tests of meshadv.victims.registry: names, lazy loading and the promised error messages."""

from __future__ import annotations

from pathlib import Path
import pytest

import meshadv.victims as victims
from meshadv.victims.registry import available_victims, load_victim


def test_available_victims_lists_every_promised_name() -> None:
    assert available_victims() == [
        "efficientnet_lite0",
        "efficientnet_lite2",
        "ssd_mobilenet_v2_coco",
        "densenet121",
        "inception_v3",
        "yolov3",
    ]


def test_unknown_name() -> None:
    with pytest.raises(ValueError, match="name must be one of"):
        load_victim("resnet9000")


def test_missing_weights_messages_say_what_to_pass(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="densenet121 needs weights="):
        load_victim("densenet121")
    with pytest.raises(ValueError, match="inception_v3 needs weights="):
        load_victim("inception_v3")
    with pytest.raises(ValueError, match="yolov3 needs weights=.*cfg="):
        load_victim("yolov3", weights=tmp_path / "yolov3.weights")
    with pytest.raises(FileNotFoundError, match="nope.pth"):
        load_victim("efficientnet_lite2", weights=tmp_path / "nope.pth")
    with pytest.raises(FileNotFoundError, match="nope.pb"):
        load_victim("ssd_mobilenet_v2_coco", weights=tmp_path / "nope.pb")
    with pytest.raises(ValueError, match="cfg"):
        load_victim("efficientnet_lite0", cfg=tmp_path / "x.cfg")


def test_package_exports() -> None:
    for name in victims.__all__:
        assert hasattr(victims, name), name
    assert victims.load_victim is load_victim
