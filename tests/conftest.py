"""Test set-up: float64 (jaxrbf turns it on at import; asserted here) and the shared data folder."""

from pathlib import Path

import jax
import pytest

import jaxrbf  # noqa: F401  (enables float64)

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"


@pytest.fixture(scope="session", autouse=True)
def _x64():
    assert jax.config.jax_enable_x64, "jaxrbf should have enabled float64"
    yield


def data_file(name: str) -> Path:
    path = DATA / name
    if not path.exists():
        pytest.skip(f"{path} is absent (the shared test meshes live in ../shared/data)")
    return path
