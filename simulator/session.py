"""Assemble a session: trajectories → sensor streams, events, truth, and wire messages."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, TypeAlias

import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from protocol import wire
from simulator import quat
from simulator.arm import ACTIVITY_RAMP_S, ArmModel, elbow_angle_deg
from simulator.config import COMPENSATORY, PHASE_NAMES, TRANSITION, SimConfig
from simulator.imu import add_errors, grid_points, imu_truth
from simulator.robot import RobotSamples, robot_samples
from simulator.subject import Subject, draw_subject, without
from simulator.truth import MAX_OUTSIDE_FRACTION, TOLERANCE_M, Cycles, Truth

F64: TypeAlias = NDArray[np.float64]
Messages: TypeAlias = list[tuple[str, dict[str, Any]]]

TIME_DECIMALS = 6  # µs stamps
CYCLE_GRID_HZ = 1000.0  # time resolution of the true outside fractions
PROGRESS_MIN_POINTS = 200_000  # ~2 s of work: below this no progress bar


@dataclass(frozen=True)
class Simulation:
    """Result of :func:`simulate`."""

    config: SimConfig
    subject: Subject  # effective parameters: errors switched off are zero here
    truth: Truth
    messages: Messages  # (contract key, payload) in arrival order
    heading_drift_dps: float  # mean vertical (world) component of the gyro bias, °/s
    n_imu_samples: int
    n_robot_samples: int

    def summary(self) -> str:
        """One line for humans."""
        c = self.truth.cycles
        counts = {name: int(np.sum(c.phase == code)) for code, name in PHASE_NAMES.items() if code}
        return (
            f"seed {self.config.seed}: {self.config.duration_s:g} s, "
            f"{self.n_imu_samples} IMU / {self.n_robot_samples} robot samples, "
            f"{len(self.messages)} messages; {len(c)} cycles "
            f"({counts['proper']} proper, {counts['compensatory']} compensatory, "
            f"{counts['transition']} transition; {int(c.compensatory.sum())} judged "
            f"compensatory); latency {self.subject.latency_s * 1e3:.0f} ms, "
            f"heading drift {self.heading_drift_dps:+.2f} °/s"
        )


def _round(x: F64, decimals: int, enabled: bool) -> F64:
    return np.round(x, decimals) if enabled else x


def _cycles(
    arm: ArmModel, spans: list[tuple[int, float, float]], duration: float, t0: float
) -> tuple[Cycles, F64]:
    """Complete cycles with their true verdicts, and every cycle start within the session."""
    phi_end = float(arm.phase(np.array([duration]))[0])
    n_starts = int(np.floor(phi_end))
    later = arm.times_at_phase(np.arange(1, n_starts + 1, dtype=np.float64))
    bounds = np.concatenate(([arm.rest_end], later))
    start, end = bounds[:-1], bounds[1:]
    labels, fractions, peaks = [], [], []
    for s, e in zip(start, end, strict=True):
        codes = {p for p, a, b in spans if a < e and b > s}
        label = codes.pop() if len(codes) == 1 else TRANSITION
        if label == COMPENSATORY and s < arm.rest_end + ACTIVITY_RAMP_S:
            label = TRANSITION  # the lean is still ramping in from the rest
        labels.append(label)
        tau = np.arange(s, e, 1.0 / CYCLE_GRID_HZ)
        disp = np.linalg.norm((arm.shoulder(tau) - arm.nominal_shoulder)[:, :2], axis=1)
        fractions.append(float(np.mean(disp > TOLERANCE_M)))
        peaks.append(float(disp.max()))
    frac = np.array(fractions)
    cycles = Cycles(
        start=start + t0,
        end=end + t0,
        phase=np.array(labels, dtype=np.int8),
        outside_fraction=frac,
        peak_displacement_m=np.array(peaks),
        compensatory=frac > MAX_OUTSIDE_FRACTION,
    )
    return cycles, bounds


def _corners(arm: ArmModel, duration: float) -> tuple[F64, F64]:
    """Times the wrist passes a rectangle corner (after the start) and its arrival direction."""
    phi_end = float(arm.phase(np.array([duration]))[0])
    cp = arm.path.corner_phase
    j = np.arange(int(np.floor(phi_end)) + 1)
    targets = (j[:, None] + cp[None, :]).ravel()
    which = np.tile(np.arange(cp.shape[0]), j.shape[0])
    keep = (targets > 0) & (targets <= phi_end)
    tau = arm.times_at_phase(targets[keep])
    d2 = arm.path.arrival_dir[which[keep]]
    return tau, np.column_stack((d2, np.zeros(d2.shape[0])))


def _messages(
    cfg: SimConfig,
    t_imu: F64,
    gyr: F64,
    acc: F64,
    robot: RobotSamples,
    t_robot: F64,
    events: list[wire.EventMessage],
) -> Messages:
    """Wire messages sorted by arrival: IMU when its last sample is taken, robot at its stamp
    (already latency-late), events at their stamp; ties IMU, then robot, then events."""
    rounded = cfg.round_output
    gyr = _round(gyr, 7, rounded)
    acc = _round(acc, 6, rounded)
    wrist = _round(robot.wrist, 6, rounded)
    prox = _round(robot.proximal, 6, rounded)
    queue: list[tuple[float, int, int, tuple[str, dict[str, Any]]]] = []
    for seq, i in enumerate(range(0, t_imu.shape[0], cfg.imu_batch)):
        sl = slice(i, i + cfg.imu_batch)
        msg = wire.ImuMessage(cfg.device, cfg.segment, t_imu[sl], gyr[sl], acc[sl], seq)
        queue.append((float(t_imu[sl][-1]), 0, seq, wire.encode(msg)))
    for seq, i in enumerate(range(0, t_robot.shape[0], cfg.robot_batch)):
        sl = slice(i, i + cfg.robot_batch)
        rmsg = wire.RobotMessage(cfg.device, t_robot[sl], wrist[sl], prox[sl], None, seq)
        queue.append((float(t_robot[sl][-1]), 1, seq, wire.encode(rmsg)))
    for k, ev in enumerate(events):
        queue.append((ev.t, 2, k, wire.encode(ev)))
    queue.sort(key=lambda item: item[:3])
    return [item[3] for item in queue]


def simulate(config: SimConfig | None = None, *, progress: bool = False) -> Simulation:
    """Simulate one session. Same config (and seed) → identical messages and truth.

    ``progress`` shows a bar on stderr when the session is long enough to take > ~2 s.
    """
    cfg = config if config is not None else SimConfig()
    seeds = np.random.SeedSequence(cfg.seed).spawn(4)
    # Independent streams: switching an error off never changes the others' draws.
    rng_subject, rng_traj, rng_imu, rng_robot = (np.random.default_rng(s) for s in seeds)
    drawn = cfg.subject if cfg.subject is not None else draw_subject(rng_subject)
    if cfg.gyro_bias_scale != 1.0:
        bx, by, bz = (cfg.gyro_bias_scale * b for b in drawn.gyro_bias_dps)
        drawn = replace(drawn, gyro_bias_dps=(bx, by, bz))
    subject = without(drawn, **cfg.switches())
    spans = cfg.spans()
    duration = cfg.duration_s
    arm = ArmModel(subject, spans, duration, rng_traj)

    # IMU
    n_imu = int(np.floor(duration * cfg.imu_rate_hz + 1e-9)) + 1
    points = grid_points(n_imu, cfg.imu_rate_hz)
    with tqdm(
        total=points,
        unit="pt",
        desc="simulate",
        leave=False,
        disable=not progress or points < PROGRESS_MIN_POINTS,
    ) as bar:
        kin = imu_truth(arm, subject, n_imu, cfg.imu_rate_hz, progress=bar.update)
    readings = add_errors(
        kin,
        subject,
        rng_imu,
        cfg.imu_rate_hz,
        gyro_noise_rad_s=cfg.gyro_noise_rad_s if cfg.enabled("gyro_noise") else 0.0,
        acc_noise_m_s2=cfg.acc_noise_m_s2 if cfg.enabled("acc_noise") else 0.0,
        gyro_bias_walk_dps=cfg.gyro_bias_walk_dps,
    )
    tau_imu = np.arange(n_imu) / cfg.imu_rate_hz
    t_imu = np.round(cfg.t0_s + tau_imu, TIME_DECIMALS)

    # Robot
    corner_tau, corner_dir = _corners(arm, duration)
    robot = robot_samples(
        arm,
        subject,
        rng_robot,
        rate_hz=cfg.robot_rate_hz,
        time_offset_s=cfg.robot_time_offset_s,
        duration_s=duration,
        cuff_to_elbow_m=cfg.cuff_to_elbow_m,
        wrist_cuff_m=cfg.wrist_cuff_m,
        noise_m=cfg.robot_noise_m if cfg.enabled("robot_noise") else 0.0,
        corner_tau=corner_tau,
        corner_dir=corner_dir,
    )
    t_robot = np.round(cfg.t0_s + robot.tau, TIME_DECIMALS)

    # Truth
    cycles, bounds = _cycles(arm, spans, duration, cfg.t0_s)
    phase = np.zeros(n_imu, dtype=np.int8)
    for code, a, b in spans:
        phase[(tau_imu >= a) & (tau_imu < b)] = code
    phase[tau_imu >= spans[-1][2]] = spans[-1][0]
    cycle = np.searchsorted(bounds, tau_imu, side="right") - 1
    cycle[(cycle < 0) | (cycle >= len(cycles))] = -1
    j = kin.pose
    disp = np.linalg.norm((j.shoulder - arm.nominal_shoulder)[:, :2], axis=1)
    truth = Truth(
        t=t_imu,
        shoulder=j.shoulder,
        elbow=j.elbow,
        wrist=j.wrist,
        elbow_angle_deg=elbow_angle_deg(j.shoulder, j.elbow, j.wrist),
        q_ra=kin.q_segment,
        q_imu=kin.q_sensor,
        imu_position=kin.position,
        gyro_bias=readings.gyro_bias,
        shoulder_displacement_m=disp,
        phase=phase,
        cycle=cycle.astype(np.int64),
        nominal_shoulder=arm.nominal_shoulder.copy(),
        corner_t=corner_tau + cfg.t0_s,
        cycles=cycles,
    )

    # Events: the therapist's shoulder reference halfway through the rest; cycle markers.
    ref_point = arm.nominal_shoulder + np.array(subject.reference_error_m)
    events = [
        wire.EventMessage(
            cfg.device,
            float(np.round(cfg.t0_s + 0.5 * arm.rest_end, TIME_DECIMALS)),
            "shoulder_reference",
            _round(ref_point, 6, cfg.round_output),
        )
    ]
    if cfg.cycle_events:
        for b in bounds:
            if b <= duration:
                events.append(
                    wire.EventMessage(
                        cfg.device, float(np.round(cfg.t0_s + b, TIME_DECIMALS)), "cycle_start"
                    )
                )

    messages = _messages(cfg, t_imu, readings.gyr, readings.acc, robot, t_robot, events)
    bias_world = quat.rotate(kin.q_sensor, readings.gyro_bias)
    drift = float(np.degrees(bias_world[:, 2].mean()))
    return Simulation(cfg, subject, truth, messages, drift, n_imu, int(robot.tau.shape[0]))
