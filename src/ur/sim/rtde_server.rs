//! The simulator's RTDE server (docs/protocols.md C2–C4, C8): the handshake, output and
//! input recipes (`NOT_FOUND` for unknown fields, `IN_USE` for registers 0–23 when a fieldbus
//! holds them), `S`/`P`, and data packages at the recipe rate stamped with the controller clock.
//! A client that stops reading is dropped after 10 s, as the controller does.

use std::io::Read as _;
use std::net::TcpStream;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use super::Faults;
use super::state::ArmState;
use crate::netio::{is_would_block, sleep_until, write_all_within};
use crate::signal::Rng;
use crate::ur::rtde::codec::{
    ClientMessage, FieldType, PacketReader, Recipe, RobotMessage, RtdeType, Setup, Value,
};
use crate::ur::rtde::fields;

/// A client that reads nothing for this long is dropped, as the controller does.
const CLIENT_READ_LIMIT: Duration = Duration::from_secs(10);

/// The controller's version the simulator reports.
pub const URCONTROL_VERSION: (u32, u32, u32, u32) = (5, 11, 1, 108_318);
/// e-Series maximum output rate.
pub const MAX_FREQUENCY_HZ: f64 = 500.0;

/// The value of the output `name` (of type `ty`, from [`fields::output_type`]) at
/// `controller_s`. What the arm's state models comes from it; the rest holds a plausible
/// constant of an idle, healthy e-Series arm (48 V supply, joints at 32 °C, no payload, no
/// I/O), so a client that records every field sees sensible numbers.
fn output_value(name: &str, ty: RtdeType, s: &ArmState, controller_s: f64) -> Value {
    let safety_bits = match s.safety.code() {
        1 => 1,
        3 => 1 << 2,
        5 => 1 << 5,
        6 | 7 => 1 << 7,
        _ => 0,
    };
    // UR joint and tool modes: 253 running, 255 idle, 239 powered off.
    let joint_mode = match s.robot_mode.code() {
        7 => 253,
        5 => 255,
        _ => 239,
    };
    match name {
        "timestamp" => Value::Double(controller_s),
        "speed_scaling" | "target_speed_fraction" => Value::Double(1.0),
        "actual_TCP_pose" => Value::Vector6d(s.pose),
        "target_TCP_pose" => Value::Vector6d(s.target_pose),
        "actual_TCP_speed" | "target_TCP_speed" => Value::Vector6d(s.speed),
        "actual_q" | "target_q" => Value::Vector6d(s.joints),
        "robot_mode" => Value::Int32(s.robot_mode.code()),
        "safety_mode" | "safety_status" => Value::Int32(s.safety.code()),
        "runtime_state" => Value::Uint32(s.runtime_state()),
        "robot_status_bits" => Value::Uint32(
            u32::from(s.robot_mode.code() >= 4) | (u32::from(s.motion.is_some()) << 1),
        ),
        "safety_status_bits" => Value::Uint32(safety_bits),
        "joint_mode" => Value::Vector6Int32([joint_mode; 6]),
        "tool_mode" => Value::Uint32(joint_mode as u32),
        "control_step" => Value::Uint64((controller_s * MAX_FREQUENCY_HZ).round().max(0.0) as u64),
        "actual_main_voltage" | "actual_robot_voltage" => Value::Double(48.0),
        "actual_robot_current" => Value::Double(0.6),
        "actual_joint_voltage" => Value::Vector6d([47.8; 6]),
        "joint_temperatures" => Value::Vector6d([32.0; 6]),
        "tool_temperature" => Value::Double(30.0),
        "target_gravity" => Value::Vector3d([0.0, 0.0, -9.82]),
        "actual_tool_accelerometer" => Value::Vector3d([0.0, 0.0, -9.82]),
        _ => {
            let index = |p: &str| name.strip_prefix(p).and_then(|i| i.parse::<usize>().ok());
            if let Some(i) = index("output_int_register_") {
                Value::Int32(s.output_int_registers.get(i).copied().unwrap_or(0))
            } else if let Some(i) = index("input_int_register_") {
                Value::Int32(s.input_int_registers.get(i).copied().unwrap_or(0))
            } else {
                zero(ty)
            }
        }
    }
}

/// The zero of `ty`.
fn zero(ty: RtdeType) -> Value {
    match ty {
        RtdeType::Bool => Value::Bool(false),
        RtdeType::Uint8 => Value::Uint8(0),
        RtdeType::Uint32 => Value::Uint32(0),
        RtdeType::Uint64 => Value::Uint64(0),
        RtdeType::Int32 => Value::Int32(0),
        RtdeType::Double => Value::Double(0.0),
        RtdeType::Vector3d => Value::Vector3d([0.0; 3]),
        RtdeType::Vector6d => Value::Vector6d([0.0; 6]),
        RtdeType::Vector6Int32 => Value::Vector6Int32([0; 6]),
        RtdeType::Vector6Uint32 => Value::Vector6Uint32([0; 6]),
    }
}

/// Connection numbers, so that input fields know their holder.
static NEXT_CLIENT: AtomicU64 = AtomicU64::new(1);

/// One connection: its number, and the input fields it holds, released when it ends however
/// it ends.
struct Client {
    id: u64,
    arm: Arc<Mutex<ArmState>>,
}

impl Client {
    fn new(arm: Arc<Mutex<ArmState>>) -> Client {
        Client {
            id: NEXT_CLIENT.fetch_add(1, Ordering::Relaxed),
            arm,
        }
    }
}

impl Drop for Client {
    fn drop(&mut self) {
        let mut arm = self.arm.lock().unwrap_or_else(|p| p.into_inner());
        arm.input_owners.retain(|_, owner| *owner != self.id);
    }
}

/// Serves one client until it leaves, stops reading for 10 s, or `stop` is set.
pub(crate) fn serve(
    mut stream: TcpStream,
    arm: Arc<Mutex<ArmState>>,
    faults: Arc<Mutex<Faults>>,
    stop: Arc<AtomicBool>,
) {
    let client = Client::new(arm.clone());
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
    let mut close_after_reply = false;
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
                        .map(|n| {
                            fields::output_type(n).map_or(FieldType::NotFound, FieldType::Type)
                        })
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
                        setup: Setup::Outputs,
                        recipe_id: 1,
                        types,
                    })
                }
                ClientMessage::SetupInputs { names } => {
                    let fieldbus = faults
                        .lock()
                        .map(|f| f.fieldbus_holds_registers)
                        .unwrap_or(false);
                    let Ok(mut arm) = arm.lock() else { return };
                    let types: Vec<FieldType> = names
                        .iter()
                        .map(|n| match input_type(n, fieldbus) {
                            FieldType::Type(_)
                                if arm.input_owners.get(n).is_some_and(|&o| o != client.id) =>
                            {
                                FieldType::InUse
                            }
                            other => other,
                        })
                        .collect();
                    let known: Option<Vec<RtdeType>> = types
                        .iter()
                        .map(|t| match t {
                            FieldType::Type(t) => Some(*t),
                            _ => None,
                        })
                        .collect();
                    // A refused recipe gets id 0 and holds nothing.
                    let recipe_id = match known {
                        Some(types) => {
                            let id = inputs.len() as u8 + 1;
                            for n in &names {
                                arm.input_owners.insert(n.clone(), client.id);
                            }
                            inputs.push(Recipe {
                                id,
                                names: names.clone(),
                                types,
                            });
                            id
                        }
                        None => 0,
                    };
                    Some(RobotMessage::SetupReply {
                        setup: Setup::Inputs,
                        recipe_id,
                        types,
                    })
                }
                ClientMessage::Start => {
                    let ok = outputs.is_some();
                    let (delay_s, close) = faults
                        .lock()
                        .map(|f| (f.first_package_delay_s.max(0.0), f.close_after_start))
                        .unwrap_or((0.0, false));
                    if ok && !streaming {
                        streaming = true;
                        tick = 0;
                        let a = arm.lock();
                        first_tick_controller_s = a
                            .map(|a| {
                                let c = a.controller_s(a.host_s(Instant::now())) + delay_s;
                                let period = outputs.as_ref().map_or(0.002, |o| 1.0 / o.1);
                                (c / period).ceil() * period
                            })
                            .unwrap_or(0.0);
                    }
                    close_after_reply = ok && close;
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
            if close_after_reply {
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
                    .zip(&recipe.types)
                    .map(|(n, t)| output_value(n, *t, &a, controller_s))
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

/// The controller's answer for the input `name`: its type, `NOT_FOUND`, or `IN_USE` for the
/// integer and double registers 0–23 while a fieldbus holds them.
fn input_type(name: &str, fieldbus_holds_low_registers: bool) -> FieldType {
    match fields::input_field(name) {
        None => FieldType::NotFound,
        Some((RtdeType::Int32 | RtdeType::Double, Some(index)))
            if index < 24 && fieldbus_holds_low_registers =>
        {
            FieldType::InUse
        }
        Some((ty, _)) => FieldType::Type(ty),
    }
}
