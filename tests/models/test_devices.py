"""One parser for dtype names, the default precision per device, and the device a backend runs on."""

import pytest
import torch

from snell_bench.models import DeviceNotAvailableError, parse_dtype
from snell_bench.models.devices import DTYPE_NAMES, default_dtype, dtype_kwarg, resolve_device


@pytest.mark.parametrize(
    "name,expected",
    [
        ("bfloat16", torch.bfloat16),
        ("bf16", torch.bfloat16),
        ("float16", torch.float16),
        ("fp16", torch.float16),
        ("half", torch.float16),
        ("float32", torch.float32),
        ("fp32", torch.float32),
        ("float", torch.float32),
        ("torch.float32", torch.float32),
        ("torch.bfloat16", torch.bfloat16),
        ("BF16", torch.bfloat16),
        (" fp16 ", torch.float16),
    ],
)
def test_names(name, expected):
    assert parse_dtype(name) is expected


def test_none_and_dtypes_pass_through():
    assert parse_dtype(None) is None
    for dt in (torch.bfloat16, torch.float16, torch.float32, torch.float64):
        assert parse_dtype(dt) is dt


def test_unknown_names_list_the_accepted_ones():
    for bad in ("float13", "int8", "torch.float64", "", "bfloat"):
        with pytest.raises(ValueError, match="model.dtype") as info:
            parse_dtype(bad)
        msg = str(info.value)
        assert all(name in msg for name in DTYPE_NAMES)
    with pytest.raises(TypeError, match="torch.dtype"):
        parse_dtype(32)


def test_default_dtype():
    assert default_dtype("cpu") is torch.float32 and default_dtype(torch.device("cuda", 0)) is torch.bfloat16


def test_dtype_kwarg():
    ((key, value),) = dtype_kwarg(torch.float16).items()
    assert key in ("dtype", "torch_dtype") and value is torch.float16  # loading with it: test_external.py


def test_resolve_device():
    assert resolve_device("cpu", unavailable="x") == torch.device("cpu")
    if torch.cuda.is_available():
        assert resolve_device(None, unavailable="x").type == "cuda"
    else:
        for dev in (None, "auto", "cuda", "cuda:1"):
            with pytest.raises(DeviceNotAvailableError, match="use the CPU"):
                resolve_device(dev, unavailable="no GPU here: use the CPU")
