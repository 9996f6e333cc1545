"""LC-Opt-style [-1, 1] scaling of observations and actions.

The ranges are LC-Opt's (temperatures 273.15..373.15 K, branch power 0..400 kW, cell fan power
0..``fan_power_nominal_w``, supply setpoint 20..40 degC, dp setpoint 25..38 psi, valves 0..1);
each env publishes its own as ``obs_scale_range`` and ``action_scale_range`` (low, high arrays
shaped like one observation or action).

Observations outside their range are clipped to [-1, 1] after scaling (a temperature of 110 degC
reads as 1.0). Actions are mapped linearly and *not* clipped here: a normalized action outside
[-1, 1] reaches the env outside its physical range, where it is clamped and reported in
``info["clamped"]``.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces


class UnitScale:
    """Elementwise affine map of [low, high] onto [-1, 1]."""

    def __init__(self, low: np.ndarray, high: np.ndarray):
        self.low = np.asarray(low, dtype=np.float64)
        self.high = np.asarray(high, dtype=np.float64)
        if self.low.shape != self.high.shape or not (self.high > self.low).all():
            raise ValueError("scale ranges need `low` < `high` elementwise, with equal shapes")
        self._gain = (2.0 / (self.high - self.low)).astype(np.float32)
        self._offset = (-1.0 - self.low * (2.0 / (self.high - self.low))).astype(np.float32)
        self._mid = 0.5 * (self.low + self.high)
        self._half = 0.5 * (self.high - self.low)

    def to_unit(self, x: np.ndarray) -> np.ndarray:
        """Scale physical ``x`` to [-1, 1] (float32, clipped)."""
        y = np.multiply(x, self._gain, dtype=np.float32)
        y += self._offset
        return np.clip(y, -1.0, 1.0, out=y)

    def from_unit(self, y: np.ndarray) -> np.ndarray:
        """Map [-1, 1] back to physical units (float64); values outside [-1, 1] map outside the range.

        Inside [-1, 1] the result is kept within [low, high], so rounding never reads as a clamp.
        """
        y = np.asarray(y, dtype=np.float64)
        x = self._mid + self._half * y
        inside = np.abs(y) <= 1.0
        if inside.all():
            return np.clip(x, self.low, self.high, out=x)
        return np.where(inside, np.clip(x, self.low, self.high), x)


class NormalizedObservation(gym.ObservationWrapper):
    """Observations scaled to [-1, 1] with the env's ``obs_scale_range``."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        low, high = _scale_range(env, "obs_scale_range")
        self.scale = UnitScale(low, high)
        self.observation_space = spaces.Box(-1.0, 1.0, shape=self.scale.low.shape, dtype=np.float32)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        return self.scale.to_unit(observation)


class NormalizedAction(gym.ActionWrapper):
    """Actions taken in [-1, 1] and mapped onto the env's ``action_scale_range`` (Box actions only)."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        if not isinstance(env.action_space, spaces.Box):
            raise TypeError(
                f"NormalizedAction needs a Box action space; {type(env.unwrapped).__name__} has "
                f"{type(env.action_space).__name__} (use make_normalized, which leaves discrete actions alone)"
            )
        low, high = _scale_range(env, "action_scale_range")
        self.scale = UnitScale(low, high)
        self.action_space = spaces.Box(-1.0, 1.0, shape=self.scale.low.shape, dtype=np.float32)

    def action(self, action: np.ndarray) -> np.ndarray:
        return self.scale.from_unit(action)


def make_normalized(env: gym.Env) -> gym.Env:
    """``env`` with normalized observations, and normalized actions where the actions are a Box."""
    env = NormalizedObservation(env)
    if isinstance(env.action_space, spaces.Box):
        env = NormalizedAction(env)
    return env


def _scale_range(env: gym.Env, name: str) -> tuple[np.ndarray, np.ndarray]:
    scale_range = getattr(env.unwrapped, name, None)
    if scale_range is None:
        raise TypeError(f"{type(env.unwrapped).__name__} publishes no `{name}`; it is not an lc-mesh env")
    return scale_range
