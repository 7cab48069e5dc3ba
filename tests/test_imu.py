"""sim.imu and the trajectories' accelerations: velocity.txt, imu.txt and their exactness."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from sim.capture_errors import RigParams
from sim.imu import (
    IMU_PRESETS,
    ImuParams,
    gravity_vector,
    ideal_imu,
    imu_generator,
    imu_noise,
    imu_times,
    read_imu,
    read_velocity,
    write_motion_truth,
)
from sim.scene import SceneError, parse_scene
from sim.se3 import (
    hat,
    look_at,
    make_pose,
    rotation_from_euler,
    so3_exp,
    so3_log,
    so3_right_jacobian,
    so3_right_jacobian_rate,
)
from sim.sequence import load_sequence
from sim.simulate import simulate
from sim.trajectory import HandheldTrajectory, LinearTrajectory, SampledTrajectory
from tests.conftest import WALL, scene_text
from tests.test_trajectory import R0, linear, spline

G = 9.80665


def handheld() -> HandheldTrajectory:
    """Fast 6-DoF shake: rotations up to 25 deg (past the Jacobians' series threshold), 1-2 Hz,
    speeding up."""
    return HandheldTrajectory(R0, [0.0, 0.5, 1.0], [0.05, 0.08, 0.03],
                              np.radians([25.0, 15.0, 20.0]), [1.1, 1.7, 0.9, 1.3, 2.1, 1.6],
                              [0.1, 1.2, 2.3, 3.4, 4.5, 5.6], chirp=0.4)


def sampled() -> SampledTrajectory:
    """Geodesic interpolation of test_trajectory's spline keyframes."""
    keys = spline()
    return SampledTrajectory(keys.times, keys.poses)


# --- analytic derivatives ---------------------------------------------------------------------

@pytest.mark.parametrize("make", [linear, handheld, spline, sampled])
def test_accelerations_match_finite_differences_of_the_velocities(make):
    """Central differences (h = 1e-5 s) of velocity() agree with acceleration() to 1e-7 of the
    largest value: the difference's truncation error is h^2/6 |jerk|, about 1e-9 here."""
    traj = make()
    h = 1e-5
    t = np.linspace(max(traj.t_start, -1.0) + 0.013, min(traj.t_end, 3.0) - 0.017, 41)
    if make is sampled:                             # the velocity jumps at the samples
        keep = np.min(np.abs(t[:, None] - traj.times[None, :]), axis=1) > 2 * h
        t = t[keep]
    v_plus, w_plus = traj.velocity(t + h)
    v_minus, w_minus = traj.velocity(t - h)
    a, alpha = traj.acceleration(t)
    a_fd, alpha_fd = (v_plus - v_minus) / (2 * h), (w_plus - w_minus) / (2 * h)
    scale = max(1.0, np.abs(a_fd).max(), np.abs(alpha_fd).max())
    np.testing.assert_allclose(a, a_fd, rtol=0, atol=1e-7 * scale)
    np.testing.assert_allclose(alpha, alpha_fd, rtol=0, atol=1e-7 * scale)
    if make is not linear:
        assert np.abs(a).max() > 0.5                # not vacuous
    if make in (handheld, spline):
        assert np.abs(alpha).max() > 0.5
    assert traj.acceleration(float(t[3]))[0].shape == (3,)


def test_second_derivative_of_the_positions_is_the_acceleration():
    """Independent of velocity(): second central differences of pose() positions."""
    traj, h = handheld(), 1e-4
    t = np.linspace(0.0, 2.0, 23)
    p = [traj.pose(t + k * h)[:, :3, 3] for k in (-1, 0, 1)]
    np.testing.assert_allclose(traj.acceleration(t)[0], (p[2] - 2 * p[1] + p[0]) / h ** 2,
                               rtol=0, atol=2e-5)


@pytest.mark.parametrize("angle", [1e-4, 0.05, 0.0999, 0.1001, 0.7, 2.5])
def test_right_jacobian_rate_matches_finite_differences(angle):
    rng = np.random.default_rng(1)
    w = rng.normal(size=3)
    w *= angle / np.linalg.norm(w)
    w_dot, h = rng.normal(size=3), 1e-6
    fd = (so3_right_jacobian(w + h * w_dot) - so3_right_jacobian(w - h * w_dot)) / (2 * h)
    np.testing.assert_allclose(so3_right_jacobian_rate(w, w_dot), fd, rtol=0, atol=1e-9)


def test_sampled_segment_acceleration_is_circular_motion():
    """A constant body twist v_b = (1, 0, 0) m/s, w_b = (0, 0, 1) rad/s is a circle of radius
    1 m: centripetal acceleration 1 m/s^2 towards the centre (+y in the body frame)."""
    T1 = make_pose(so3_exp([0.0, 0.0, 1.0]), [math.sin(1.0), 1.0 - math.cos(1.0), 0.0])
    traj = SampledTrajectory([0.0, 1.0], np.stack([np.eye(4), T1]))
    t = np.array([0.0, 0.3, 0.8])
    a, alpha = traj.acceleration(t)
    R = traj.pose(t)[:, :3, :3]
    np.testing.assert_allclose(np.einsum("nji,nj->ni", R, a), [[0.0, 1.0, 0.0]] * 3, atol=1e-12)
    np.testing.assert_array_equal(alpha, 0.0)


# --- the ideal IMU ----------------------------------------------------------------------------

def _integrate(samples: np.ndarray, rate: float, R0: np.ndarray, v0: np.ndarray,
               p0: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """RK4 of dR/dt = R hat(gyro), dv/dt = R acc + g, dp/dt = v with steps of 2 samples
    (the middle sample is the half step). Returns the rotations and positions at every
    other sample."""
    def f(state, k):
        R, v = state[0:9].reshape(3, 3), state[9:12]
        acc, gyro = samples[k, :3], samples[k, 3:]
        return np.concatenate([(R @ hat(gyro)).ravel(), R @ acc + g, v])

    h = 2.0 / rate
    state = np.concatenate([R0.ravel(), v0, p0])
    rotations, positions = [R0], [p0]
    for k in range(0, len(samples) - 2, 2):
        k1 = f(state, k)
        k2 = f(state + h / 2 * k1, k + 1)
        k3 = f(state + h / 2 * k2, k + 1)
        k4 = f(state + h * k3, k + 2)
        state = state + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        rotations.append(state[0:9].reshape(3, 3))
        positions.append(state[12:15])
    return np.array(rotations), np.array(positions)


EXTRINSIC = make_pose(rotation_from_euler([10.0, -20.0, 90.0]), [0.05, -0.03, 0.02])


def _check_integration(traj, samples: np.ndarray, times: np.ndarray, rate: float,
                       T_ci: np.ndarray, g: np.ndarray) -> tuple[float, float]:
    """Integrate the IMU from the true initial state; the errors (m, rad) against the IMU's
    true pose T_world_camera T_camera_imu at every other sample."""
    T_wc = traj.pose(times[0])
    v_w, w_w = traj.velocity(times[0])
    R_wi = T_wc[:3, :3] @ T_ci[:3, :3]
    lever = T_wc[:3, :3] @ T_ci[:3, 3]
    rotations, positions = _integrate(samples, rate, R_wi, v_w + np.cross(w_w, lever),
                                      T_wc[:3, 3] + lever, g)
    true = traj.pose(times[::2][:len(positions)]) @ T_ci
    position_error = np.linalg.norm(positions - true[:, :3, 3], axis=1).max()
    rotation_error = np.linalg.norm(
        so3_log(np.swapaxes(true[:, :3, :3], 1, 2) @ rotations), axis=1).max()
    return float(position_error), float(rotation_error)


@pytest.mark.parametrize("T_ci", [np.eye(4), EXTRINSIC], ids=["identity", "extrinsic"])
@pytest.mark.parametrize("make", [handheld, spline])
def test_noiseless_imu_integrates_back_to_the_trajectory(make, T_ci):
    """1 s at 1 kHz, RK4 on 2 ms steps: the IMU's pose comes back within 1e-8 m and 1e-8 rad
    (RK4's error, O(h^4): measured 7.5e-10 m and 2.8e-10 rad on the handheld motion; a missing
    lever-arm term, a gravity sign or a frame mix-up gives centimetres)."""
    traj, rate = make(), 1000.0
    times = imu_times(0.2, 1.2, rate)
    g = gravity_vector([0.0, 0.0, 1.0])
    acc, gyro = ideal_imu(traj, times, g, T_ci)
    position_error, rotation_error = _check_integration(
        traj, np.concatenate([acc, gyro], axis=1), times, rate, T_ci, g)
    assert position_error < 1e-8 and rotation_error < 1e-8
    # The bound is tight: without the lever arm's terms the same integration is far off.
    if T_ci is EXTRINSIC:
        wrong, _ = ideal_imu(traj, times, g, make_pose(T_ci[:3, :3], np.zeros(3)))
        off, _ = _check_integration(traj, np.concatenate([wrong, gyro], axis=1), times, rate,
                                    T_ci, g)
        assert off > 1e-3


def test_at_rest_the_accelerometer_reads_gravity_up_and_the_gyro_zero():
    """A still camera looking along +y with z up (its y axis points down): the specific force
    is +9.80665 m/s^2 up, that is (0, -g, 0) in the camera frame; an IMU turned 90 deg about
    the camera's z (its x axis = the camera's y, down) reads (-g, 0, 0)."""
    still = LinearTrajectory([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], look_at([0, 0, 0], [0, 1, 0]))
    t = np.linspace(0.0, 1.0, 5)
    acc, gyro = ideal_imu(still, t, gravity_vector([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(acc, [[0.0, -G, 0.0]] * 5, atol=1e-12)
    np.testing.assert_array_equal(gyro, 0.0)
    turned = make_pose(rotation_from_euler([0.0, 0.0, 90.0]), [0.3, 0.0, 0.0])
    acc, _ = ideal_imu(still, t, gravity_vector([0.0, 0.0, 1.0]), turned)
    np.testing.assert_allclose(acc, [[-G, 0.0, 0.0]] * 5, atol=1e-12)
    # another up: a world with y up reads +g along the camera's -z (it looks up the y axis)
    acc, _ = ideal_imu(still, t, gravity_vector([0.0, 2.0, 0.0]))
    np.testing.assert_allclose(acc, [[0.0, 0.0, G]] * 5, atol=1e-12)


def test_spinning_imu_feels_the_centripetal_acceleration():
    """The camera spins at 2 rad/s about its z axis (its optical axis, here the world's z, with
    gravity along z); an IMU 0.1 m along the camera's x feels -w^2 r = (-0.4, 0, 0) plus
    gravity, and the same angular velocity."""
    T1 = make_pose(so3_exp([0.0, 0.0, 2.0]), [0.0, 0.0, 0.0])
    spin = SampledTrajectory([0.0, 1.0], np.stack([np.eye(4), T1]))
    acc, gyro = ideal_imu(spin, [0.25, 0.5], gravity_vector([0.0, 0.0, -1.0]),
                          make_pose(np.eye(3), [0.1, 0.0, 0.0]))
    np.testing.assert_allclose(acc, [[-0.4, 0.0, -G]] * 2, atol=1e-12)
    np.testing.assert_allclose(gyro, [[0.0, 0.0, 2.0]] * 2, atol=1e-12)


# --- noise ------------------------------------------------------------------------------------

def _allan_deviation(x: np.ndarray, m: int) -> np.ndarray:
    """Overlapping Allan deviation of (N, K) samples at a cluster of m samples, per column."""
    c = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum(x, axis=0)])
    means = (c[m:] - c[:-m]) / m
    d = means[m:] - means[:-m]
    return np.sqrt(0.5 * np.mean(d * d, axis=0))


def test_white_noise_allan_deviation_at_one_second_is_the_density():
    """Allan deviation of white noise of density sigma is sigma / sqrt(tau): at tau = 1 s, within
    10 % for each of the 6 axes (2000 s at 200 Hz: about 2 % expected scatter)."""
    params = ImuParams(rate=200.0, accelerometer_noise_density=4e-3,
                       gyroscope_noise_density=9e-5)
    noise, bias = imu_noise(400_000, params, np.random.default_rng(7))
    np.testing.assert_array_equal(bias, 0.0)
    adev = _allan_deviation(noise, 200)
    expected = np.repeat([4e-3, 9e-5], 3)
    np.testing.assert_allclose(adev, expected, rtol=0.10)
    # the per-sample deviation is sigma sqrt(rate) (Kalibr's discretisation)
    np.testing.assert_allclose(noise.std(axis=0), expected * math.sqrt(200.0), rtol=0.02)


def test_bias_random_walk_grows_as_the_square_root_of_time():
    """Bias increments over L seconds have deviation sigma_b sqrt(L): 1 s and 10 s lags within
    10 %, and the Allan deviation at tau = 10 s follows sigma_b sqrt(tau / 3) within 15 %
    (200 clusters: about 5 % scatter; measured 0.93-1.07)."""
    params = ImuParams(rate=200.0, accelerometer_random_walk=2e-4, gyroscope_random_walk=4e-6)
    noise, bias = imu_noise(400_000, params, np.random.default_rng(8))
    np.testing.assert_array_equal(noise, bias)
    np.testing.assert_array_equal(bias[0], 0.0)
    walk = np.repeat([2e-4, 4e-6], 3)
    for lag_s in (1, 10):
        steps = np.diff(bias[:: 200 * lag_s], axis=0)
        np.testing.assert_allclose(steps.std(axis=0), walk * math.sqrt(lag_s), rtol=0.10)
    adev = _allan_deviation(noise, 200 * 10)
    np.testing.assert_allclose(adev, walk * math.sqrt(10 / 3), rtol=0.15)


def test_noise_is_seeded_and_its_own_stream():
    params = IMU_PRESETS["mpu6150"]
    a, _ = imu_noise(100, params, imu_generator(3))
    b, _ = imu_noise(100, params, imu_generator(3))
    c, _ = imu_noise(100, params, imu_generator(4))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    from sim.capture_errors import rig_generator
    assert not np.allclose(imu_generator(3).standard_normal(5),
                           rig_generator(3, "poses").standard_normal(5))


# --- scene keys -------------------------------------------------------------------------------

def test_imu_scene_keys():
    extra = ('up = [0.0, 0.0, 2.0]\n[imu]\npreset = "mpu6150"\nrate = 500.0\n'
             "T_camera_imu = { translation = [0.01, 0.02, 0.03], rotation = [0.0, 0.0, 90.0] }\n")
    scene = parse_scene(scene_text(WALL, extra=extra))
    assert scene.up == (0.0, 0.0, 1.0)
    assert scene.imu.rate == 500.0 and scene.imu.preset == "mpu6150"
    assert scene.imu.gyroscope_noise_density == pytest.approx(math.radians(0.005))
    np.testing.assert_allclose(scene.imu.extrinsic[:3, 3], [0.01, 0.02, 0.03])
    np.testing.assert_allclose(scene.imu.extrinsic[:3, :3] @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0],
                               atol=1e-12)
    custom = parse_scene(scene_text(WALL, extra='[imu]\npreset = "mpu6150"\n'
                                                "gyroscope_random_walk = 1e-5\n")).imu
    assert custom.preset == "custom" and custom.gyroscope_random_walk == 1e-5
    default = parse_scene(scene_text(WALL))
    assert default.imu == IMU_PRESETS["ideal"] and default.up == (0.0, 0.0, 1.0)


@pytest.mark.parametrize(("extra", "message"), [
    ("[imu]\nrate = 0.0\n", r"\[imu\].rate: expected a positive number"),
    ("[imu]\ngyroscope_noise_density = -1e-4\n",
     r"\[imu\].gyroscope_noise_density: expected a number >= 0"),
    ('[imu]\npreset = "adis"\n', r"\[imu\].preset: expected one of ideal, mpu6150"),
    ("[imu]\nnoise = 1.0\n", r"\[imu\]: unknown key 'noise'"),
    ("[imu]\nT_camera_imu = { translation = [0.0, 0.0] }\n",
     r"\[imu\].T_camera_imu.translation: expected a list of 3"),
    ("[imu]\nT_camera_imu = { t = [0.0, 0.0, 0.0] }\n", r"\[imu\].T_camera_imu: unknown key 't'"),
    ("up = [0.0, 0.0, 0.0]\n", r"up: expected a non-zero direction"),
    ("[rig]\nimu_offset = true\n", r"\[rig\].imu_offset: expected a finite number"),
])
def test_bad_imu_keys_are_refused_in_one_line(extra, message):
    with pytest.raises(SceneError, match=message) as info:
        parse_scene(scene_text(WALL, extra=extra))
    assert "\n" not in str(info.value)


def test_imu_params_are_checked():
    with pytest.raises(ValueError, match="imu rate must be a finite number > 0"):
        ImuParams(rate=-1.0)
    with pytest.raises(ValueError, match="T_camera_imu must be a rigid transform"):
        ImuParams(T_camera_imu=2 * np.eye(4))


# --- the files --------------------------------------------------------------------------------

HANDHELD = ('[trajectory]\ntype = "handheld"\nposition = [0.0, 0.0, 0.0]\n'
            "look_at = [0.0, 1.0, 0.0]\ntranslation_amplitude = [0.05, 0.04, 0.03]\n"
            "rotation_amplitude = [8.0, 6.0, 10.0]\nfrequencies = [1.1, 1.7, 0.9, 1.3, 2.1, 1.6]\n"
            "chirp = 0.3\n")
SMALL = ("[camera]\nwidth = 48\nheight = 36\nfx = 45.0\nfy = 40.0\ncx = 23.5\ncy = 17.5\n"
         "distortion = [-0.1, 0.02, 0.001, -0.001, 0.0]\n")
IMU_EXTRA = ("[frames]\nrate = 4.0\nexposure = 0.005\nexposure_samples = 1\n[render]\nspp = 1\n"
             "pose_rate = 250.0\n[rig]\npreset = \"mocap\"\nimu_offset = 0.004\n"
             '[imu]\npreset = "mpu6150"\n'
             "T_camera_imu = { translation = [0.05, -0.03, 0.02], "
             "rotation = [10.0, -20.0, 90.0] }\n")


@pytest.fixture(scope="module")
def imu_sequence(tmp_path_factory):
    scene = parse_scene(scene_text(WALL, camera=SMALL, trajectory=HANDHELD, duration=1.3,
                                   extra=IMU_EXTRA))
    out = tmp_path_factory.mktemp("imu") / "seq"
    return scene, simulate(scene, out, start=0.1, duration=1.1, progress=False,
                           with_events=False).out


def test_velocity_txt_is_the_camera_twist_of_the_poses(imu_sequence):
    """velocity.txt against central differences of the true poses (an independent
    computation): R^T dp/dt and so3_log(R(t-h)^T R(t+h)) / 2h, within 1e-6."""
    scene, out = imu_sequence
    data = load_sequence(out).read_velocity()
    truth = np.loadtxt(out / "groundtruth_exact.txt")
    np.testing.assert_array_equal(data[:, 0], truth[:, 0])         # the pose times, true clock
    assert len(data) == 276 and data[0, 0] == 0.1                   # 1.1 s at 250 Hz
    t, h, traj = data[1:-1, 0], 1e-5, scene.trajectory
    plus, minus = traj.pose(t + h), traj.pose(t - h)
    R = traj.pose(t)[:, :3, :3]
    v = np.einsum("nji,nj->ni", R, (plus[:, :3, 3] - minus[:, :3, 3]) / (2 * h))
    w = so3_log(np.swapaxes(minus[:, :3, :3], 1, 2) @ plus[:, :3, :3]) / (2 * h)
    np.testing.assert_allclose(data[1:-1, 1:4], v, rtol=0, atol=1e-6)
    np.testing.assert_allclose(data[1:-1, 4:], w, rtol=0, atol=1e-6)
    assert np.abs(data[:, 4:]).max() > 0.1


def test_imu_files_integrate_back_and_carry_the_declared_noise(imu_sequence):
    scene, out = imu_sequence
    seq = load_sequence(out)
    noisy, exact = seq.read_imu(), read_imu(out / "imu_exact.txt")
    assert seq.imu_path == out / "imu.txt" and seq.velocity_path == out / "velocity.txt"
    assert len(exact) == 1101                                      # [0.1, 1.2] s at 1 kHz
    np.testing.assert_allclose(exact[:, 0], 0.1 + np.arange(1101) / 1000.0, atol=1e-12)
    np.testing.assert_allclose(noisy[:, 0], exact[:, 0] + 0.004, atol=1e-12)   # imu_offset
    # the exact IMU read back from the file integrates to the true pose of the IMU
    T_ci = scene.imu.extrinsic
    position_error, rotation_error = _check_integration(
        scene.trajectory, exact[:, 1:], exact[:, 0], 1000.0, T_ci, np.array([0.0, 0.0, -G]))
    assert position_error < 1e-8 and rotation_error < 1e-8, (position_error,
                                                            rotation_error)
    # the noisy one: white noise of the mpu6150's density (per sample sigma sqrt(rate))
    params = IMU_PRESETS["mpu6150"]
    difference = noisy[:, 1:] - exact[:, 1:]
    expected = np.repeat([params.accelerometer_noise_density,
                          params.gyroscope_noise_density], 3) * math.sqrt(1000.0)
    np.testing.assert_allclose(difference.std(axis=0), expected, rtol=0.15)
    meta = json.loads((out / "sequence.json").read_text())["imu"]
    assert meta["params"]["preset"] == "mpu6150" and meta["count"] == 1101
    assert meta["stream"] == [3, 0x494D55] and meta["offset_s"] == 0.004
    assert meta["gravity_world_m_s2"] == [0.0, 0.0, -G]
    np.testing.assert_allclose(meta["params"]["T_camera_imu"], T_ci)


def test_ideal_imu_writes_the_exact_file_twice(tmp_path):
    """Without noise and offset imu.txt has the bytes of imu_exact.txt, and a still camera
    reads gravity up (written without rendering: write_motion_truth alone)."""
    scene = parse_scene(scene_text(WALL, duration=0.2))
    record = write_motion_truth(tmp_path, scene, 0.0, 0.2)
    assert (tmp_path / "imu.txt").read_bytes() == (tmp_path / "imu_exact.txt").read_bytes()
    data = read_imu(tmp_path / "imu.txt")
    assert record["ideal"] and len(data) == 201
    np.testing.assert_allclose(data[:, 1:], [[0.0, -G, 0.0, 0.0, 0.0, 0.0]] * 201, atol=1e-12)
    np.testing.assert_array_equal(read_velocity(tmp_path / "velocity.txt")[:, 1:], 0.0)


def test_rig_imu_offset_is_checked_like_the_others(tmp_path):
    scene = parse_scene(scene_text(WALL, duration=0.2))
    with pytest.raises(ValueError, match="rig imu_offset -0.01 s would write imu times"):
        simulate(scene, tmp_path / "seq", progress=False, with_events=False,
                 rig=RigParams(imu_offset=-0.01))


@pytest.mark.parametrize(("body", "message"), [
    ("0.0 1 2 3 4 5\n", r"imu.txt:1: expected 't ax ay az gx gy gz' \(7 numbers\), got 6"),
    ("0.0 1 2 3 4 5 x\n", r"imu.txt:1: 'x' is not a number"),
    ("0.1 1 2 3 4 5 6\n0.1 1 2 3 4 5 6\n", r"imu.txt:2: time 0.1 is not after"),
])
def test_malformed_imu_files_name_the_line(tmp_path, body, message):
    path = tmp_path / "imu.txt"
    path.write_text(body)
    with pytest.raises(ValueError, match=message):
        read_imu(path)
