"""The error / reference-activity front of an identified loop, against LTI systems whose responses are known
exactly: the impulse response, the front's least-squares points (a second solver on the exact Toeplitz
matrix), and steering flown on the predictor never below the front."""

import numpy as np
import pytest
import scipy.linalg as sl

from support.lti import LTI, height_loop
from ddpc_codegen import IODataset, SteeringConfig, SteeringProblem, fit_predictor
from ddpc_codegen.design.front import (desired_from_trajectory, fly_on_model, follow_on_model, front_error_at,
                                       impulse_response, operating_point, point_of, reference_front)
from ddpc_codegen.errors import ConfigError

TI, TF = 6, 30


@pytest.fixture(scope="module")
def loop():
    sys_ = height_loop()
    u = np.random.default_rng(4).standard_normal((800, 2))
    y, _ = sys_.simulate(u, np.zeros(3))
    return sys_, fit_predictor(IODataset(u, y, 0.005), TI, TF, "lsq")


def _steps(n: int = 240) -> np.ndarray:
    """A level, a step up, a step down (quintic ramps over 10 samples); the second output stays at 0."""
    q = lambda k: np.clip((np.arange(n) - k) / 10.0, 0, 1)  # noqa: E731
    ramp = lambda x: x**3 * (10 - 15 * x + 6 * x**2)  # noqa: E731
    z = 1.0 + 0.3 * ramp(q(60)) - 0.2 * ramp(q(150))
    return np.column_stack([z, np.zeros(n)])


def _exact_toeplitz(sys_: LTI, n: int) -> np.ndarray:
    pulse = np.zeros((n, 2))
    pulse[0, 0] = 1.0
    h = sys_.simulate(pulse, np.zeros(3))[0][:, 0]
    return sl.toeplitz(h, np.zeros(n))


def test_the_impulse_response_is_the_loops_exact_one(loop):
    sys_, pred = loop
    T = _exact_toeplitz(sys_, 200)
    np.testing.assert_allclose(impulse_response(pred, 0, 0, 200), T[:, 0], atol=1e-9)
    np.testing.assert_allclose(operating_point(pred, np.array([1.0, 0.0])), [1.0, 0.0], atol=1e-8)
    with pytest.raises(ValueError, match="does not move"):
        point_of(np.zeros(5), np.ones(5), np.ones(5))


def test_each_front_point_is_the_least_squares_optimum_of_the_exact_loop(loop):
    sys_, pred = loop
    des = _steps()
    n = des.shape[0]
    T = _exact_toeplitz(sys_, n)
    e = des[:, 0] - 1.0  # at rest at the operating point of the start: y0 = u0 = 1.0
    D = (np.eye(n, k=1) - np.eye(n))[:-1]
    front = reference_front(pred, des, relative_weights=(1e-3, 1e-1, 10.0))
    for p in front:
        # a second solver on the exact loop: the stacked least-squares problem
        du = np.linalg.lstsq(np.vstack([T, np.sqrt(p.weight) * D]), np.concatenate([e, np.zeros(n - 1)]), rcond=None)[0]
        want = point_of(T @ du - e, 1.0 + du, des[:, 0])
        assert p.error_rms == pytest.approx(want.error_rms, rel=1e-6)
        assert p.rate_ratio == pytest.approx(want.rate_ratio, rel=1e-6)
    # a heavier rate weight: a calmer reference and a larger error, every time
    assert all(a.rate_ratio > b.rate_ratio and a.error_rms < b.error_rms for a, b in zip(front, front[1:]))
    with pytest.raises(ValueError, match="desired must be"):
        reference_front(pred, des[:, 0])
    # a caller's impulse response (the exact one here) gives the same points; one of the wrong length is refused
    given = reference_front(pred, des, relative_weights=(1e-3, 1e-1, 10.0), impulse=T[:, 0])
    assert [p.error_rms for p in given] == pytest.approx([p.error_rms for p in front], rel=1e-6)
    with pytest.raises(ValueError, match=r"impulse must be \(240,\)"):
        reference_front(pred, des, impulse=T[:-1, 0])


def test_steering_flown_on_the_predictor_is_never_below_the_front(loop):
    sys_, pred = loop
    des = _steps()
    front = reference_front(pred, des, relative_weights=tuple(np.logspace(-6, 4, 41)))
    for r_du in (0.3, 3.0, 30.0):
        cfg = SteeringConfig(t_ini=TI, t_f=TF, m=2, p=2, Q=[10.0, 1.0], R=[1e-6, 1.0], R_du=[r_du, 0.0],
                             lambda_sigma=1e3, u_min=[-5.0, -5.0], u_max=[5.0, 5.0])
        u, y = fly_on_model(SteeringProblem(pred, cfg), des)
        # the predictor as its plant is the exact loop: the same outputs from the same references
        exact, _ = sys_.simulate(u, np.array([1.0, 1.0, 0.0]))
        np.testing.assert_allclose(y, exact, atol=1e-7)
        flown = point_of(y[:, 0] - des[:, 0], u[:, 0], des[:, 0])
        # above every supporting line of the front: its weighted cost is at least each front point's
        n, base2 = des.shape[0], np.mean(np.diff(des[:, 0]) ** 2)
        cost = lambda p, w: n * p.error_rms**2 + w * (n - 1) * base2 * p.rate_ratio**2  # noqa: E731
        assert all(cost(flown, p.weight) >= cost(p, p.weight) * (1 - 1e-9) for p in front), (r_du, flown)
        assert np.isfinite(front_error_at(front, flown.rate_ratio))
    # passthrough (the desired path as the reference) is a point above the front too
    passthrough = point_of(_exact_toeplitz(sys_, des.shape[0]) @ (des[:, 0] - 1.0) - (des[:, 0] - 1.0), des[:, 0],
                           des[:, 0])
    assert passthrough.rate_ratio == pytest.approx(1.0)
    assert passthrough.error_rms > front_error_at(front, 1.0)
    assert np.isnan(front_error_at(front, 1e9))


def test_the_predictor_as_plant_follows_given_references_and_an_unsolved_tick_is_an_error(loop):
    sys_, pred = loop
    des = _steps(80)
    u = np.column_stack([des[:, 0] + 0.05 * np.sin(np.arange(80) / 5.0), 0.1 * np.cos(np.arange(80) / 7.0)])
    np.testing.assert_allclose(follow_on_model(pred, u, des), sys_.simulate(u, np.array([1.0, 1.0, 0.0]))[0],
                               atol=1e-7)
    # z_ref must start >= 2 m but may move 1 cm per tick from the 1 m it held: no reference satisfies both
    cfg = SteeringConfig(t_ini=TI, t_f=TF, m=2, p=2, Q=[10.0, 1.0], R=[1e-6, 1.0], lambda_sigma=1e3,
                         u_min=[2.0, -5.0], u_max=[5.0, 5.0], du_max=[0.01, 1.0])
    with pytest.raises(RuntimeError, match="not solved at sample 0"):
        fly_on_model(SteeringProblem(pred, cfg), des)


class _Ramp:
    """A trajectory with one channel ``z`` = t over 0..2 s (time_span / sample, as a loaded trajectory file)."""

    def time_span(self) -> tuple[float, float]:
        return 0.0, 2.0

    def sample(self, t):
        return {"z": np.asarray(t, float), "x": np.zeros_like(t)}


def test_desired_outputs_come_from_the_trajectory_channel_on_the_config_tick():
    cfg = SteeringConfig(t_ini=TI, t_f=TF, m=2, p=2, Q=[1.0, 1.0], R=[1.0, 1.0], dt=0.5, output_names=("z", "pitch"))
    desired, index = desired_from_trajectory(cfg, _Ramp(), "z", None)
    assert index == 0 and desired.shape == (4, 2)
    np.testing.assert_array_equal(desired[:, 0], [0.0, 0.5, 1.0, 1.5])
    np.testing.assert_array_equal(desired[:, 1], 0.0)
    assert desired_from_trajectory(cfg, _Ramp(), "z", 1.0)[0].shape == (2, 2)


@pytest.mark.parametrize("output, duration, message", [("yaw", None, "not one of the config's outputs"),
                                                      ("pitch", None, "has no channel 'pitch'"),
                                                      ("z", 0.0, "give --duration")])
def test_desired_outputs_refuse_a_channel_or_span_they_cannot_give(output, duration, message):
    cfg = SteeringConfig(t_ini=TI, t_f=TF, m=2, p=2, Q=[1.0, 1.0], R=[1.0, 1.0], dt=0.5, output_names=("z", "pitch"))
    with pytest.raises(ConfigError, match=message):
        desired_from_trajectory(cfg, _Ramp(), output, duration)
