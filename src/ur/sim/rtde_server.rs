//! The simulator's RTDE server (docs/protocols.md C2–C4, C8): the handshake, output and
//! input recipes (`NOT_FOUND` for unknown fields, `IN_USE` for registers 0–23 when a fieldbus
//! holds them), `S`/`P`, and data packages at the recipe rate stamped with the controller clock.
//! A client that stops reading is dropped after 10 s, as the controller does.

use std::io::Read as _;
use std::net::TcpStream;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use super::Faults;
use super::state::ArmState;
use crate::netio::{is_would_block, sleep_until, write_all_within};
use crate::signal::Rng;
use crate::ur::rtde::codec::{
    ClientMessage, FieldType, PacketReader, Recipe, RobotMessage, RtdeType, Value,
};

/// A client that reads nothing for this long is dropped, as the controller does.
const CLIENT_READ_LIMIT: Duration = Duration::from_secs(10);

/// The controller's version the simulator reports.
pub const URCONTROL_VERSION: (u32, u32, u32, u32) = (5, 11, 1, 108_318);
/// e-Series maximum output rate.
pub const MAX_FREQUENCY_HZ: f64 = 500.0;

/// The type of an output field, if the simulator knows it.
pub fn output_type(name: &str) -> Option<RtdeType> {
    Some(match name {
        "timestamp" | "speed_scaling" | "target_speed_fraction" => RtdeType::Double,
        "actual_TCP_pose" | "target_TCP_pose" | "actual_TCP_speed" | "target_TCP_speed"
        | "actual_q" | "target_q" | "actual_qd" | "target_qd" | "tcp_offset" => RtdeType::Vector6d,
        "robot_mode" | "safety_mode" | "safety_status" => RtdeType::Int32,
        "runtime_state" | "robot_status_bits" | "safety_status_bits" => RtdeType::Uint32,
        "actual_digital_output_bits" => RtdeType::Uint64,
        n => {
            if let Some(i) = n.strip_prefix("output_int_register_") {
                (i.parse::<usize>().ok()? < 48).then_some(RtdeType::Int32)?
            } else if let Some(i) = n.strip_prefix("output_double_register_") {
                (i.parse::<usize>().ok()? < 48).then_some(RtdeType::Double)?
            } else {
                return None;
            }
        }
    })
}

fn output_value(name: &str, s: &ArmState, controller_s: f64) -> Value {
    let safety_bits = match s.safety.code() {
        1 => 1,
        3 => 1 << 2,
        5 => 1 << 5,
        6 | 7 => 1 << 7,
        _ => 0,
    };
    match name {
        "timestamp" => Value::Double(controller_s),
        "speed_scaling" | "target_speed_fraction" => Value::Double(1.0),
        "actual_TCP_pose" => Value::Vector6d(s.pose),
        "target_TCP_pose" => Value::Vector6d(s.target_pose),
        "actual_TCP_speed" | "target_TCP_speed" => Value::Vector6d(s.speed),
        "actual_q" | "target_q" => Value::Vector6d(s.joints),
        "actual_qd" | "target_qd" | "tcp_offset" => Value::Vector6d([0.0; 6]),
        "robot_mode" => Value::Int32(s.robot_mode.code()),
        "safety_mode" | "safety_status" => Value::Int32(s.safety.code()),
        "runtime_state" => Value::Uint32(s.runtime_state()),
        "robot_status_bits" => Value::Uint32(
            u32::from(s.robot_mode.code() >= 4) | (u32::from(s.motion.is_some()) << 1),
        ),
        "safety_status_bits" => Value::Uint32(safety_bits),
        "actual_digital_output_bits" => Value::Uint64(0),
        n => {
            let index = |p: &str| n.strip_prefix(p).and_then(|i| i.parse::<usize>().ok());
            if let Some(i) = index("output_int_register_") {
                Value::Int32(s.output_int_registers.get(i).copied().unwrap_or(0))
            } else {
                Value::Double(0.0)
            }
        }
    }
}

/// Serves one client until it leaves, stops reading for 10 s, or `stop` is set.
pub(crate) fn serve(
    mut stream: TcpStream,
    arm: Arc<Mutex<ArmState>>,
    faults: Arc<Mutex<Faults>>,
    stop: Arc<AtomicBool>,
) {
    stream.set_nodelay(true).ok();
    // A modest send buffer, so a client that stops reading is noticed in seconds, not minutes.
    socket2::SockRef::from(&stream)
        .set_send_buffer_size(16 << 10)
        .ok();
    if stream.set_nonblocking(true).is_err() {
        return;
    }
    let mut reader = PacketReader::default();
    let mut protocol = 1u16;
    let mut outputs: Option<(Recipe, f64)> = None;
    let mut inputs: Vec<Recipe> = Vec::new();
    let mut streaming = false;
    let mut tick = 0u64;
    let mut first_tick_controller_s = 0.0;
    let mut rng = Rng::new(faults.lock().map(|f| f.seed).unwrap_or(0));
    let mut buf = [0u8; 4096];
    while !stop.load(Ordering::Relaxed) {
        let now = Instant::now();
        let (next_send, period) = match (&outputs, streaming) {
            (Some((_, f)), true) => {
                let period = 1.0 / f;
                let c = first_tick_controller_s + tick as f64 * period;
                let due = arm
                    .lock()
                    .map(|a| a.boot + Duration::from_secs_f64(controller_to_host(&a, c).max(0.0)))
                    .unwrap_or(now);
                (Some(due), period)
            }
            _ => (None, 0.0),
        };
        let mut got_input = false;
        loop {
            match stream.read(&mut buf) {
                Ok(0) => return,
                Ok(n) => {
                    reader.feed(&buf[..n]);
                    got_input = true;
                }
                Err(e) if is_would_block(&e) => break,
                Err(_) => return,
            }
        }
        if !got_input && next_send.is_none_or(|t| Instant::now() < t) {
            sleep_until(next_send, Duration::from_millis(2));
        }
        loop {
            let packet = match reader.next_packet() {
                Ok(Some(p)) => p,
                Ok(None) => break,
                Err(_) => return,
            };
            let Ok(message) = ClientMessage::decode(packet.0, &packet.1, protocol) else {
                continue;
            };
            let reply = match message {
                ClientMessage::RequestProtocolVersion(v) => {
                    let v1_only = faults.lock().map(|f| f.protocol_v1_only).unwrap_or(false);
                    let ok = v == 1 || (v == 2 && !v1_only);
                    if ok {
                        protocol = v;
                    }
                    Some(RobotMessage::ProtocolVersionAccepted(ok))
                }
                ClientMessage::GetUrcontrolVersion => {
                    let (major, minor, bugfix, build) = URCONTROL_VERSION;
                    Some(RobotMessage::UrcontrolVersion {
                        major,
                        minor,
                        bugfix,
                        build,
                    })
                }
                ClientMessage::SetupOutputs {
                    frequency_hz,
                    names,
                } => {
                    let types: Vec<FieldType> = names
                        .iter()
                        .map(|n| output_type(n).map_or(FieldType::NotFound, FieldType::Type))
                        .collect();
                    let all_known: Option<Vec<RtdeType>> = types
                        .iter()
                        .map(|t| match t {
                            FieldType::Type(t) => Some(*t),
                            _ => None,
                        })
                        .collect();
                    let f = if protocol >= 2 {
                        frequency_hz
                    } else {
                        MAX_FREQUENCY_HZ
                    };
                    if let Some(types) = all_known
                        && f > 0.0
                        && f <= MAX_FREQUENCY_HZ
                    {
                        outputs = Some((
                            Recipe {
                                id: 1,
                                names: names.clone(),
                                types,
                            },
                            f,
                        ));
                    }
                    Some(RobotMessage::SetupReply {
                        recipe_id: 1,
                        types,
                    })
                }
                ClientMessage::SetupInputs { names } => {
                    let fieldbus = faults
                        .lock()
                        .map(|f| f.fieldbus_holds_registers)
                        .unwrap_or(false);
                    let types: Vec<FieldType> =
                        names.iter().map(|n| input_type(n, fieldbus)).collect();
                    let id = inputs.len() as u8 + 1;
                    let known: Option<Vec<RtdeType>> = types
                        .iter()
                        .map(|t| match t {
                            FieldType::Type(t) => Some(*t),
                            _ => None,
                        })
                        .collect();
                    if let Some(types) = known {
                        inputs.push(Recipe {
                            id,
                            names: names.clone(),
                            types,
                        });
                    }
                    Some(RobotMessage::SetupReply {
                        recipe_id: if types.iter().all(|t| matches!(t, FieldType::Type(_))) {
                            id
                        } else {
                            0
                        },
                        types,
                    })
                }
                ClientMessage::Start => {
                    let ok = outputs.is_some();
                    if ok && !streaming {
                        streaming = true;
                        tick = 0;
                        let a = arm.lock();
                        first_tick_controller_s = a
                            .map(|a| {
                                let c = a.controller_s(a.host_s(Instant::now()));
                                let period = outputs.as_ref().map_or(0.002, |o| 1.0 / o.1);
                                (c / period).ceil() * period
                            })
                            .unwrap_or(0.0);
                    }
                    Some(RobotMessage::StartAccepted(ok))
                }
                ClientMessage::Pause => {
                    streaming = false;
                    Some(RobotMessage::PauseAccepted(true))
                }
                ClientMessage::Data { recipe_id, fields } => {
                    if let Some(r) = inputs.iter().find(|r| r.id == recipe_id)
                        && let Ok(values) = r.decode_fields(&fields)
                        && let Ok(mut a) = arm.lock()
                    {
                        a.apply_inputs(&r.names, &values, Instant::now());
                    }
                    None
                }
            };
            if let Some(reply) = reply
                && let Ok(bytes) = reply.encode(protocol)
                && write_all_within(&mut stream, &bytes, CLIENT_READ_LIMIT).is_err()
            {
                return;
            }
        }
        let (Some(due), Some((recipe, _))) = (next_send, &outputs) else {
            continue;
        };
        if !streaming || Instant::now() < due {
            continue;
        }
        let controller_s = first_tick_controller_s + tick as f64 * period;
        tick += 1;
        let (stalled, jitter_s) = faults
            .lock()
            .map(|f| {
                (
                    f.stall_until.is_some_and(|t| Instant::now() < t),
                    f.jitter_s,
                )
            })
            .unwrap_or((false, 0.0));
        if stalled {
            continue;
        }
        if jitter_s > 0.0 {
            std::thread::sleep(Duration::from_secs_f64(jitter_s * rng.uniform()));
        }
        let values: Vec<Value> = match arm.lock() {
            Ok(mut a) => {
                let host_s = controller_to_host(&a, controller_s);
                a.advance(host_s);
                recipe
                    .names
                    .iter()
                    .map(|n| output_value(n, &a, controller_s))
                    .collect()
            }
            Err(_) => return,
        };
        let mut fields = Vec::with_capacity(recipe.data_len());
        if recipe.encode_fields(&values, &mut fields).is_err() {
            return;
        }
        let message = RobotMessage::Data {
            recipe_id: recipe.id,
            fields,
        };
        match message.encode(protocol) {
            Ok(bytes) => {
                if write_all_within(&mut stream, &bytes, CLIENT_READ_LIMIT).is_err() {
                    // Unread for 10 s, or gone: the controller drops the client.
                    return;
                }
            }
            Err(_) => return,
        }
    }
}

fn controller_to_host(a: &ArmState, controller_s: f64) -> f64 {
    (controller_s - a.clock_offset_s) / (1.0 + a.clock_drift_ppm * 1e-6)
}

fn input_type(name: &str, fieldbus_holds_low_registers: bool) -> FieldType {
    let register = |prefix: &str| {
        name.strip_prefix(prefix)
            .and_then(|i| i.parse::<usize>().ok())
    };
    let (index, ty) = if let Some(i) = register("input_int_register_") {
        (i, RtdeType::Int32)
    } else if let Some(i) = register("input_double_register_") {
        (i, RtdeType::Double)
    } else {
        return match name {
            "speed_slider_mask" => FieldType::Type(RtdeType::Uint32),
            "speed_slider_fraction" => FieldType::Type(RtdeType::Double),
            _ => FieldType::NotFound,
        };
    };
    if index >= 48 {
        FieldType::NotFound
    } else if index < 24 && fieldbus_holds_low_registers {
        FieldType::InUse
    } else {
        FieldType::Type(ty)
    }
}
