"""A state mid-bend with random joint velocities: what the momentum checks run on."""

import mujoco
import numpy as np
import pytest

from cmrt.body.character import character
from cmrt.motion.taskfile import load_task


@pytest.fixture
def state():
    ch = character()
    m = ch.model
    d = mujoco.MjData(m)
    rng = np.random.default_rng(0)
    d.qpos[:] = load_task("bend").reference(np.array([1.2]))[0][0]
    d.qvel[:] = rng.normal(scale=0.8, size=m.nv)
    mujoco.mj_forward(m, d)
    return ch, m, d, rng
