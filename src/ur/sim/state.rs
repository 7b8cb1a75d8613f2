//! The simulated arm's state, advanced in time: modes, safety, the TCP pose under a `movel`'s
//! trapezoidal velocity profile, and the controller clock.

use std::collections::VecDeque;
use std::time::Instant;

use crate::ur::dashboard::{RobotMode, SafetyStatus};

/// `runtime_state` codes (C4).
pub const RUNTIME_STOPPED: u32 = 1;
pub const RUNTIME_PLAYING: u32 = 2;

/// A straight-line move at constant acceleration to `v`, cruise, and deceleration (v²/2a ramps;
/// a triangle when the line is too short to reach `v`).
#[derive(Debug, Clone, PartialEq)]
pub struct LinearMove {
    pub from: [f64; 6],
    pub to: [f64; 6],
    pub speed_m_per_s: f64,
    pub accel_m_per_s2: f64,
    pub started_s: f64,
}

impl LinearMove {
    fn length_m(&self) -> f64 {
        (0..3)
            .map(|i| (self.to[i] - self.from[i]).powi(2))
            .sum::<f64>()
            .sqrt()
    }

    /// Peak speed, ramp time and total time.
    fn profile(&self) -> (f64, f64, f64) {
        let (l, a) = (self.length_m(), self.accel_m_per_s2.max(1e-9));
        let v = self.speed_m_per_s.min((l * a).sqrt()).max(1e-9);
        let ramp_t = v / a;
        let cruise = (l - v * ramp_t).max(0.0) / v;
        (v, ramp_t, 2.0 * ramp_t + cruise)
    }

    /// Duration of the move, seconds.
    pub fn duration_s(&self) -> f64 {
        self.profile().2
    }

    /// Distance along the line and speed at `t` seconds after the start.
    fn progress(&self, t: f64) -> (f64, f64) {
        let (v, ramp_t, total) = self.profile();
        let a = self.accel_m_per_s2;
        let l = self.length_m();
        if t <= 0.0 {
            (0.0, 0.0)
        } else if t < ramp_t {
            (0.5 * a * t * t, a * t)
        } else if t < total - ramp_t {
            (0.5 * a * ramp_t * ramp_t + v * (t - ramp_t), v)
        } else if t < total {
            let left = total - t;
            (l - 0.5 * a * left * left, a * left)
        } else {
            (l, 0.0)
        }
    }

    /// Pose and TCP speed (linear part) at `now_s`.
    pub fn sample(&self, now_s: f64) -> ([f64; 6], [f64; 6]) {
        let (s, speed) = self.progress(now_s - self.started_s);
        let l = self.length_m().max(1e-12);
        let f = s / l;
        let mut pose = self.from;
        let mut twist = [0.0; 6];
        for (i, p) in pose.iter_mut().enumerate() {
            *p = self.from[i] + f * (self.to[i] - self.from[i]);
        }
        for (i, t) in twist.iter_mut().take(3).enumerate() {
            *t = speed * (self.to[i] - self.from[i]) / l;
        }
        (pose, twist)
    }
}

/// Everything RTDE and the Dashboard report.
#[derive(Debug, Clone)]
pub struct ArmState {
    pub boot: Instant,
    pub robot_mode: RobotMode,
    pub safety: SafetyStatus,
    pub remote_control: bool,
    pub pose: [f64; 6],
    pub target_pose: [f64; 6],
    pub speed: [f64; 6],
    pub joints: [f64; 6],
    pub motion: Option<LinearMove>,
    /// Moves started since boot (each `movel` statement).
    pub moves_started: u64,
    pub output_int_registers: [i32; 48],
    pub input_int_registers: [i32; 48],
    /// Input fields held by an RTDE client's input recipe, with the client's connection
    /// number: another client asking for one gets `IN_USE` until the holder disconnects.
    pub input_owners: std::collections::HashMap<String, u64>,
    /// Controller clock: offset (s) and drift (ppm) against the host's monotonic clock.
    pub clock_offset_s: f64,
    pub clock_drift_ppm: f64,
    /// Seconds after the start of this move number (0-based) at which a protective stop fires.
    pub protective_stop: Option<(u64, f64)>,
    /// Seconds after the start of this move number (0-based) from which every RTDE input
    /// package is lost until the move ends: a host that stalls, as the controller sees it.
    pub input_loss: Option<(u64, f64)>,
    /// The running program's RTDE watchdog.
    pub watchdog: Option<Watchdog>,
    pub watchdog_trips: u64,
    /// Recent finished or cut moves with the host second each ended, oldest first.
    pub track: VecDeque<(LinearMove, f64)>,
}

/// Finished moves kept for [`ArmState::pose_at`].
const TRACK_LEN: usize = 64;

/// `rtde_set_watchdog(variable, min_frequency, "stop")` of the running program.
#[derive(Debug, Clone, PartialEq)]
pub struct Watchdog {
    pub variable: String,
    pub min_frequency_hz: f64,
    /// Host seconds since boot of the variable's last update.
    pub last_update_s: f64,
}

impl ArmState {
    pub fn new(pose: [f64; 6]) -> Self {
        Self {
            boot: Instant::now(),
            robot_mode: RobotMode::Running,
            safety: SafetyStatus::Normal,
            remote_control: true,
            pose,
            target_pose: pose,
            speed: [0.0; 6],
            joints: [0.0, -1.57, 1.57, -1.57, -1.57, 0.0],
            motion: None,
            moves_started: 0,
            output_int_registers: [0; 48],
            input_int_registers: [0; 48],
            input_owners: std::collections::HashMap::new(),
            clock_offset_s: 0.0,
            clock_drift_ppm: 0.0,
            protective_stop: None,
            input_loss: None,
            watchdog: None,
            watchdog_trips: 0,
            track: VecDeque::new(),
        }
    }

    /// Ends the running move at `end_s` and files it in the track.
    fn close_motion(&mut self, end_s: f64) {
        if let Some(m) = self.motion.take() {
            if self.track.len() == TRACK_LEN {
                self.track.pop_front();
            }
            self.track.push_back((m, end_s));
        }
    }

    /// The TCP pose at host second `t_s`, given the state advanced to `now_s`: from the track
    /// for the past, from the running move for the rest of that move (as planned: a stop not
    /// yet issued is not foreseen), and `None` for a time that no known motion decides yet.
    pub fn pose_at(&self, t_s: f64, now_s: f64) -> Option<[f64; 6]> {
        if t_s > now_s {
            let m = self.motion.as_ref()?;
            return (t_s <= m.started_s + m.duration_s()).then(|| m.sample(t_s).0);
        }
        let running = self.motion.iter().map(|m| (m, f64::INFINITY));
        let finished = self.track.iter().rev().map(|(m, end)| (m, *end));
        let mut oldest = None;
        for (m, end_s) in running.chain(finished) {
            if m.started_s <= t_s {
                return Some(m.sample(t_s.min(end_s)).0);
            }
            oldest = Some(m.from);
        }
        // Before every known move: where the oldest one started, or here if none ever did.
        Some(oldest.unwrap_or(self.pose))
    }

    /// Applies an RTDE input package.
    pub fn apply_inputs(
        &mut self,
        names: &[String],
        values: &[crate::ur::rtde::Value],
        now: Instant,
    ) {
        let now_s = self.host_s(now);
        if let (Some((index, after_s)), Some(m)) = (self.input_loss, &self.motion)
            && self.moves_started == index + 1
            && now_s >= m.started_s + after_s
        {
            return;
        }
        for (name, value) in names.iter().zip(values) {
            if let (Some(i), crate::ur::rtde::Value::Int32(v)) = (
                name.strip_prefix("input_int_register_")
                    .and_then(|i| i.parse::<usize>().ok()),
                value,
            ) && let Some(slot) = self.input_int_registers.get_mut(i)
            {
                *slot = *v;
            }
            if let Some(w) = self.watchdog.as_mut()
                && &w.variable == name
            {
                w.last_update_s = now_s;
            }
        }
    }

    /// Arms the program's watchdog.
    pub fn set_watchdog(&mut self, variable: String, min_frequency_hz: f64, now: Instant) {
        let last_update_s = self.host_s(now);
        self.watchdog = Some(Watchdog {
            variable,
            min_frequency_hz,
            last_update_s,
        });
    }

    /// Seconds since boot on the host's clock.
    pub fn host_s(&self, now: Instant) -> f64 {
        now.saturating_duration_since(self.boot).as_secs_f64()
    }

    /// The controller's `timestamp` at host time `host_s`.
    pub fn controller_s(&self, host_s: f64) -> f64 {
        self.clock_offset_s + host_s * (1.0 + self.clock_drift_ppm * 1e-6)
    }

    /// `runtime_state`: playing while a move runs.
    pub fn runtime_state(&self) -> u32 {
        if self.motion.is_some() {
            RUNTIME_PLAYING
        } else {
            RUNTIME_STOPPED
        }
    }

    /// Starts a `movel` (it preempts a running one), if the arm may move.
    pub fn start_move(&mut self, to: [f64; 6], speed: f64, accel: f64, now: Instant) -> bool {
        let now_s = self.host_s(now);
        self.advance(now_s);
        if self.robot_mode != RobotMode::Running || self.safety.is_stop() {
            return false;
        }
        self.close_motion(now_s);
        self.motion = Some(LinearMove {
            from: self.pose,
            to,
            speed_m_per_s: speed,
            accel_m_per_s2: accel,
            started_s: now_s,
        });
        self.target_pose = to;
        self.moves_started += 1;
        true
    }

    /// Stops motion at once (`stopl`, Dashboard `stop`).
    pub fn stop(&mut self, now: Instant) {
        let now_s = self.host_s(now);
        self.advance(now_s);
        self.close_motion(now_s);
        self.watchdog = None;
        self.speed = [0.0; 6];
        self.target_pose = self.pose;
    }

    /// Moves the state to host time `now_s`.
    pub fn advance(&mut self, now_s: f64) {
        let Some(m) = self.motion.clone() else {
            return;
        };
        if let Some(w) = &self.watchdog {
            let deadline = w.last_update_s + 1.0 / w.min_frequency_hz.max(1e-3);
            if now_s > deadline {
                let (pose, _) = m.sample(deadline);
                self.pose = pose;
                self.target_pose = pose;
                self.speed = [0.0; 6];
                self.close_motion(deadline);
                self.watchdog = None;
                self.watchdog_trips += 1;
                return;
            }
        }
        if let Some((index, after_s)) = self.protective_stop
            && self.moves_started == index + 1
            && now_s >= m.started_s + after_s
        {
            let (pose, _) = m.sample(m.started_s + after_s);
            self.pose = pose;
            self.target_pose = pose;
            self.speed = [0.0; 6];
            self.close_motion(m.started_s + after_s);
            self.safety = SafetyStatus::ProtectiveStop;
            self.protective_stop = None;
            return;
        }
        let (pose, twist) = m.sample(now_s);
        self.pose = pose;
        self.speed = twist;
        if now_s >= m.started_s + m.duration_s() {
            // The program ends with its move, and its watchdog with it.
            self.pose = m.to;
            self.speed = [0.0; 6];
            self.close_motion(m.started_s + m.duration_s());
            self.watchdog = None;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_at_reads_the_past_from_the_track_and_the_running_move_ahead() {
        let mut arm = ArmState::new([0.0; 6]);
        let boot = arm.boot;
        let at = |s: f64| boot + std::time::Duration::from_secs_f64(s);
        assert!(arm.start_move([0.1, 0.0, 0.0, 0.0, 0.0, 0.0], 0.1, 1.0, at(1.0)));
        arm.advance(5.0);
        assert!(arm.start_move([0.1, 0.2, 0.0, 0.0, 0.0, 0.0], 0.1, 1.0, at(6.0)));
        arm.advance(6.5);
        let now_s = 6.5;
        assert_eq!(arm.pose_at(0.5, now_s), Some([0.0; 6]), "before any move");
        let first = arm.track[0].0.clone();
        assert_eq!(arm.pose_at(1.5, now_s), Some(first.sample(1.5).0));
        assert_eq!(
            arm.pose_at(5.5, now_s).map(|p| p[0]),
            Some(0.1),
            "resting between"
        );
        let second = arm.motion.clone().unwrap();
        assert_eq!(
            arm.pose_at(7.0, now_s),
            Some(second.sample(7.0).0),
            "planned ahead"
        );
        assert_eq!(
            arm.pose_at(20.0, now_s),
            None,
            "after the move nothing is decided"
        );
    }

    #[test]
    fn a_movel_follows_its_trapezoid() {
        let m = LinearMove {
            from: [0.0; 6],
            to: [0.5, 0.0, 0.0, 0.0, 0.0, 0.0],
            speed_m_per_s: 0.25,
            accel_m_per_s2: 1.0,
            started_s: 10.0,
        };
        // Ramps of 0.25 s over 31.25 mm each, cruise (500 − 62.5) mm / 0.25 m/s = 1.75 s.
        assert!((m.duration_s() - 2.25).abs() < 1e-12);
        let (p, v) = m.sample(10.125);
        assert!((p[0] - 0.5 * 0.125f64.powi(2)).abs() < 1e-12 && (v[0] - 0.125).abs() < 1e-12);
        let (p, v) = m.sample(11.0);
        assert!((p[0] - (0.03125 + 0.25 * 0.75)).abs() < 1e-12 && (v[0] - 0.25).abs() < 1e-12);
        let (p, v) = m.sample(13.0);
        assert_eq!((p[0], v[0]), (0.5, 0.0));
    }
}
