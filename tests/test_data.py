"""The bundled recordings: rebuilt byte for byte by the generator, readable, labelled synthetic."""
import importlib.util
import sys
from pathlib import Path

import pytest

from tvcid.models.recording import load_recording

DATA = Path(__file__).resolve().parents[1] / "data"


def _generator():
    spec = importlib.util.spec_from_file_location("data_generate", DATA / "generate.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def test_generator_reproduces_bundled_files(tmp_path):
    gen = _generator()
    sums = gen.checksums(gen.build(tmp_path))
    expected = gen.read_sums(DATA / "SHA256SUMS")
    assert set(sums) == set(expected)
    for name, digest in expected.items():
        assert sums[name] == digest, f"{name} differs from data/SHA256SUMS"
        assert gen.checksums([DATA / name])[name] == digest, f"bundled {name} was edited"


@pytest.mark.parametrize("name", ["m000_closed_A", "m000_closed_B", "m000_open_square", "m000_open_sine"])
def test_bundled_recordings_load_and_say_synthetic(name):
    rec = load_recording(DATA / f"{name}.csv")
    assert rec.meta["source"] == "simulated"
    assert rec.meta["hypothesis"] == "M000"
    assert rec.sample_rate == pytest.approx(1000.0)
    assert rec.kind == ("closed" if "closed" in name else "open")
