import pytest

pytest.importorskip("mujoco")
