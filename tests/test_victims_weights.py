"""Weight files that cannot be used raise ValueError naming the file; devices are checked before loading."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch

from meshadv.victims import load_victim
from meshadv.victims._weights import check_device, read_torch_state


class _Payload:
    """An object whose unpickling would run code."""

    def __reduce__(self) -> tuple:
        return (os.system, ("echo pwned",))


def _files(tmp_path: Path) -> dict[str, Path]:
    good = tmp_path / "good.pth"
    torch.save({"w": torch.ones(2)}, good)
    data = good.read_bytes()
    files = {"good": good}
    for name, content in {
        "empty": b"",
        "truncated": data[: len(data) // 2],
        "garbage": bytes(range(256)) * 4,
    }.items():
        files[name] = tmp_path / f"{name}.pth"
        files[name].write_bytes(content)
    files["pickled"] = tmp_path / "pickled.pth"
    torch.save({"w": _Payload()}, files["pickled"])
    return files


@pytest.mark.parametrize(
    ("name", "match"),
    [
        ("empty", "is empty"),
        ("truncated", "is truncated or corrupted"),
        ("garbage", "is not a torch weights file"),
        ("pickled", "carries pickled Python objects"),
    ],
)
def test_unusable_weight_files_raise_value_error_naming_the_file(tmp_path: Path, name: str, match: str) -> None:
    path = _files(tmp_path)[name]
    with pytest.raises(ValueError, match=match) as info:
        read_torch_state(path)
    assert str(path) in str(info.value)
    with pytest.raises(ValueError, match=match):
        load_victim("densenet121", weights=path)


def test_a_good_file_loads_and_a_missing_one_is_file_not_found(tmp_path: Path) -> None:
    assert torch.equal(read_torch_state(_files(tmp_path)["good"])["w"], torch.ones(2))
    with pytest.raises(FileNotFoundError, match="nope.pth"):
        read_torch_state(tmp_path / "nope.pth")


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the message on a machine without CUDA")
def test_cuda_without_cuda_fails_before_reading_weights(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="CUDA is not available"):
        load_victim("densenet121", weights=tmp_path / "not-read.pth", device="cuda")


def test_device_types_and_names() -> None:
    assert check_device("cpu") == torch.device("cpu")
    with pytest.raises(TypeError, match="device must be a string"):
        check_device(0)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="is not a torch device"):
        check_device("gpu")
    with pytest.raises(ValueError, match="^name must be one of .*did you mean 'densenet121'"):
        load_victim("densenet12")
