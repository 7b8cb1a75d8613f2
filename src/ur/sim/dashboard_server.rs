//! The simulator's Dashboard server: the greeting and the replies of docs/protocols.md C6.
//! In Local mode every command that acts is refused with the controller's text; queries answer.

use std::io::{BufRead as _, BufReader, Write as _};
use std::net::TcpStream;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use super::state::ArmState;
use crate::ur::dashboard::{LOCAL_MODE_REFUSAL, RobotMode, SafetyStatus};

/// Commands that only read state, answered in Local mode too.
const QUERIES: &[&str] = &[
    "robotmode",
    "safetystatus",
    "safetymode",
    "programState",
    "running",
    "is in remote control",
    "PolyscopeVersion",
    "version",
    "get robot model",
    "get serial number",
    "get loaded program",
    "quit",
];

/// The reply to one command line.
pub(crate) fn reply(arm: &mut ArmState, command: &str, now: Instant) -> String {
    let command = command.trim();
    let now_s = arm.host_s(now);
    arm.advance(now_s);
    if !arm.remote_control && !QUERIES.contains(&command) {
        return LOCAL_MODE_REFUSAL.to_string();
    }
    match command {
        "robotmode" => format!("Robotmode: {}", arm.robot_mode.name()),
        "safetystatus" => format!("Safetystatus: {}", arm.safety.name()),
        "safetymode" => format!("Safetymode: {}", arm.safety.name()),
        "programState" => {
            let state = if arm.motion.is_some() {
                "PLAYING"
            } else {
                "STOPPED"
            };
            format!("{state} <unnamed>")
        }
        "running" => format!("Program running: {}", arm.motion.is_some()),
        "is in remote control" => arm.remote_control.to_string(),
        "PolyscopeVersion" => "URSoftware 5.11.1.108318 (Nov 25 2021)".into(),
        "version" => "5.11.1.108318".into(),
        "get robot model" => "UR5".into(),
        "get serial number" => "20205500000".into(),
        "get loaded program" => "Loaded program: <unnamed>".into(),
        "power on" => {
            if arm.robot_mode != RobotMode::Running {
                arm.robot_mode = RobotMode::Idle;
            }
            "Powering on".into()
        }
        "power off" => {
            arm.stop(now);
            arm.robot_mode = RobotMode::PowerOff;
            "Powering off".into()
        }
        "brake release" => {
            if matches!(arm.robot_mode, RobotMode::Idle | RobotMode::PowerOn) {
                arm.robot_mode = RobotMode::Running;
            }
            "Brake releasing".into()
        }
        "stop" => {
            arm.stop(now);
            "Stopped".into()
        }
        "unlock protective stop" => {
            if arm.safety == SafetyStatus::ProtectiveStop {
                arm.safety = SafetyStatus::Normal;
            }
            "Protective stop releasing".into()
        }
        "close safety popup" => "closing safety popup".into(),
        "close popup" => "closing popup".into(),
        other if other.starts_with("addToLog ") => "Added log message".into(),
        other => format!("could not understand: '{other}'"),
    }
}

pub(crate) fn serve(stream: TcpStream, arm: Arc<Mutex<ArmState>>, stop: Arc<AtomicBool>) {
    stream
        .set_read_timeout(Some(Duration::from_millis(50)))
        .ok();
    let Ok(mut writer) = stream.try_clone() else {
        return;
    };
    if writer
        .write_all(b"Connected: Universal Robots Dashboard Server\n")
        .is_err()
    {
        return;
    }
    let mut reader = BufReader::new(stream);
    let mut line = String::new();
    while !stop.load(Ordering::Relaxed) {
        match reader.read_line(&mut line) {
            Ok(0) => return,
            Ok(_) => {}
            Err(e) if crate::netio::is_would_block(&e) => continue,
            Err(_) => return,
        }
        if !line.ends_with('\n') {
            continue;
        }
        let command = std::mem::take(&mut line);
        let text = match arm.lock() {
            Ok(mut a) => reply(&mut a, &command, Instant::now()),
            Err(_) => return,
        };
        if writer.write_all(format!("{text}\n").as_bytes()).is_err() || command.trim() == "quit" {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn local_mode_refuses_actions_but_answers_queries() {
        let mut arm = ArmState::new([0.0; 6]);
        arm.remote_control = false;
        let now = Instant::now();
        assert_eq!(reply(&mut arm, "power on", now), LOCAL_MODE_REFUSAL);
        assert_eq!(reply(&mut arm, "robotmode", now), "Robotmode: RUNNING");
        assert_eq!(reply(&mut arm, "is in remote control", now), "false");
        arm.remote_control = true;
        assert_eq!(reply(&mut arm, "stop", now), "Stopped");
        assert_eq!(reply(&mut arm, "frob", now), "could not understand: 'frob'");
    }
}
