//! The e-Series controller's RTDE field tables (UR's RTDE guide, software 5.x): every output a
//! client may subscribe to and every input it may write, with its wire type. A setup request
//! is answered from these tables: a known name gets its type, any other `NOT_FOUND`
//! (docs/protocols.md C3, C4).
//!
//! Registers are listed as ranges: `output_int_register_0` … `_47` and so on. Bit registers
//! 0–63 are read and written as two `UINT32` words, 64–127 one `BOOL` each.

use super::codec::RtdeType;

use RtdeType::{Bool, Double, Int32, Uint8, Uint32, Uint64, Vector3d, Vector6Int32, Vector6d};

/// The named outputs (registers apart), in the order of UR's table.
const OUTPUTS: &[(&str, RtdeType)] = &[
    ("timestamp", Double),
    ("target_q", Vector6d),
    ("target_qd", Vector6d),
    ("target_qdd", Vector6d),
    ("target_current", Vector6d),
    ("target_moment", Vector6d),
    ("actual_q", Vector6d),
    ("actual_qd", Vector6d),
    ("actual_current", Vector6d),
    ("actual_current_window", Vector6d),
    ("actual_current_as_torque", Vector6d),
    ("joint_control_output", Vector6d),
    ("actual_TCP_pose", Vector6d),
    ("actual_TCP_speed", Vector6d),
    ("actual_TCP_force", Vector6d),
    ("target_TCP_pose", Vector6d),
    ("target_TCP_speed", Vector6d),
    ("tcp_offset", Vector6d),
    ("actual_TCP_acceleration", Vector6d),
    ("target_TCP_acceleration", Vector6d),
    ("actual_digital_input_bits", Uint64),
    ("actual_configurable_digital_input_bits", Uint64),
    ("joint_temperatures", Vector6d),
    ("actual_execution_time", Double),
    ("target_execution_time", Double),
    ("robot_mode", Int32),
    ("joint_mode", Vector6Int32),
    ("safety_mode", Int32),
    ("safety_status", Int32),
    ("actual_tool_accelerometer", Vector3d),
    ("speed_scaling", Double),
    ("target_speed_fraction", Double),
    ("actual_momentum", Double),
    ("actual_main_voltage", Double),
    ("actual_robot_voltage", Double),
    ("actual_robot_current", Double),
    ("actual_joint_voltage", Vector6d),
    ("actual_digital_output_bits", Uint64),
    ("actual_configurable_digital_output_bits", Uint64),
    ("runtime_state", Uint32),
    ("elbow_position", Vector3d),
    ("elbow_velocity", Vector3d),
    ("robot_status_bits", Uint32),
    ("safety_status_bits", Uint32),
    ("analog_io_types", Uint32),
    ("standard_analog_input0", Double),
    ("standard_analog_input1", Double),
    ("standard_analog_output0", Double),
    ("standard_analog_output1", Double),
    ("io_current", Double),
    ("euromap67_input_bits", Uint32),
    ("euromap67_output_bits", Uint32),
    ("euromap67_24V_voltage", Double),
    ("euromap67_24V_current", Double),
    ("tool_mode", Uint32),
    ("tool_analog_input_types", Uint32),
    ("tool_analog_input0", Double),
    ("tool_analog_input1", Double),
    ("tool_output_voltage", Int32),
    ("tool_output_current", Double),
    ("tool_temperature", Double),
    ("tcp_force_scalar", Double),
    ("output_bit_registers0_to_31", Uint32),
    ("output_bit_registers32_to_63", Uint32),
    ("input_bit_registers0_to_31", Uint32),
    ("input_bit_registers32_to_63", Uint32),
    ("actual_robot_energy_consumed", Double),
    ("actual_robot_braking_energy_dissipated", Double),
    ("encoder0_raw", Int32),
    ("encoder1_raw", Int32),
    ("tool_output_mode", Uint8),
    ("tool_digital_output0_mode", Uint8),
    ("tool_digital_output1_mode", Uint8),
    ("joint_position_deviation_ratio", Double),
    ("collision_detection_ratio", Double),
    ("ft_raw_wrench", Vector6d),
    ("wrench_calc_from_currents", Vector6d),
    ("payload", Double),
    ("payload_cog", Vector3d),
    ("payload_inertia", Vector6d),
    ("script_control_line", Uint32),
    ("time_scale_source", Int32),
    ("target_gravity", Vector3d),
    ("target_base_acceleration", Vector6d),
    ("control_step", Uint64),
    ("target_base_wrench", Vector6d),
];

/// The named inputs (registers apart).
const INPUTS: &[(&str, RtdeType)] = &[
    ("speed_slider_mask", Uint32),
    ("speed_slider_fraction", Double),
    ("standard_digital_output_mask", Uint8),
    ("standard_digital_output", Uint8),
    ("configurable_digital_output_mask", Uint8),
    ("configurable_digital_output", Uint8),
    ("tool_digital_output_mask", Uint8),
    ("tool_digital_output", Uint8),
    ("standard_analog_output_mask", Uint8),
    ("standard_analog_output_type", Uint8),
    ("standard_analog_output_0", Double),
    ("standard_analog_output_1", Double),
    ("external_force_torque", Vector6d),
    ("input_bit_registers0_to_31", Uint32),
    ("input_bit_registers32_to_63", Uint32),
];

/// A register family: `{prefix}{index}` for index in `range`, of type `ty`.
struct Registers {
    prefix: &'static str,
    range: std::ops::Range<usize>,
    ty: RtdeType,
}

const OUTPUT_REGISTERS: &[Registers] = &[
    Registers {
        prefix: "output_bit_register_",
        range: 64..128,
        ty: Bool,
    },
    Registers {
        prefix: "output_int_register_",
        range: 0..48,
        ty: Int32,
    },
    Registers {
        prefix: "output_double_register_",
        range: 0..48,
        ty: Double,
    },
];

/// The input registers; they can be read back as outputs too.
const INPUT_REGISTERS: &[Registers] = &[
    Registers {
        prefix: "input_bit_register_",
        range: 64..128,
        ty: Bool,
    },
    Registers {
        prefix: "input_int_register_",
        range: 0..48,
        ty: Int32,
    },
    Registers {
        prefix: "input_double_register_",
        range: 0..48,
        ty: Double,
    },
];

/// The register family and index `name` names, if any. The index is written in decimal
/// without leading zeros or sign, as the controller spells it.
fn register(families: &[Registers], name: &str) -> Option<(RtdeType, usize)> {
    families.iter().find_map(|f| {
        let digits = name.strip_prefix(f.prefix)?;
        let canonical = !digits.is_empty()
            && digits.bytes().all(|b| b.is_ascii_digit())
            && (digits == "0" || !digits.starts_with('0'));
        let index: usize = digits.parse().ok().filter(|_| canonical)?;
        f.range.contains(&index).then_some((f.ty, index))
    })
}

/// The type of the output field `name`; None where the controller answers `NOT_FOUND`.
pub fn output_type(name: &str) -> Option<RtdeType> {
    OUTPUTS
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, t)| *t)
        .or_else(|| register(OUTPUT_REGISTERS, name).map(|(t, _)| t))
        .or_else(|| register(INPUT_REGISTERS, name).map(|(t, _)| t))
}

/// The type of the input field `name` and, for a register, its index; None where the
/// controller answers `NOT_FOUND`.
pub fn input_field(name: &str) -> Option<(RtdeType, Option<usize>)> {
    INPUTS
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, t)| (*t, None))
        .or_else(|| register(INPUT_REGISTERS, name).map(|(t, i)| (t, Some(i))))
}

/// Every output name, registers expanded (for tests and documentation).
pub fn output_names() -> Vec<String> {
    let mut names = expand(OUTPUTS, OUTPUT_REGISTERS);
    names.extend(expand(&[], INPUT_REGISTERS));
    names
}

/// Every input name, registers expanded.
pub fn input_names() -> Vec<String> {
    expand(INPUTS, INPUT_REGISTERS)
}

fn expand(named: &[(&str, RtdeType)], registers: &[Registers]) -> Vec<String> {
    named
        .iter()
        .map(|(n, _)| n.to_string())
        .chain(
            registers
                .iter()
                .flat_map(|f| f.range.clone().map(move |i| format!("{}{i}", f.prefix))),
        )
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The table's size and a sample of each kind of entry; names differ only where the
    /// controller's do (`standard_analog_output0` is an output, `standard_analog_output_0` an
    /// input).
    #[test]
    fn the_tables_hold_every_field_once_with_its_type() {
        let outputs = output_names();
        let inputs = input_names();
        assert_eq!(outputs.len(), OUTPUTS.len() + 64 + 48 + 48 + 64 + 48 + 48);
        assert!(outputs.len() > 390, "{}", outputs.len());
        let unique: std::collections::HashSet<_> = outputs.iter().collect();
        assert_eq!(unique.len(), outputs.len());
        assert!(outputs.iter().all(|n| output_type(n).is_some()));
        assert!(inputs.iter().all(|n| input_field(n).is_some()));
        for (name, ty) in [
            ("target_qdd", Vector6d),
            ("joint_mode", Vector6Int32),
            ("payload_cog", Vector3d),
            ("actual_main_voltage", Double),
            ("tool_output_mode", Uint8),
            ("output_bit_register_127", Bool),
            ("output_double_register_47", Double),
            ("input_int_register_0", Int32),
        ] {
            assert_eq!(output_type(name), Some(ty), "{name}");
        }
        assert_eq!(
            input_field("input_int_register_24"),
            Some((Int32, Some(24)))
        );
        assert_eq!(
            input_field("standard_analog_output_0"),
            Some((Double, None))
        );
        for unknown in [
            "",
            "actual_tcp_pose",
            "output_int_register_48",
            "output_bit_register_63",
            "output_int_register_024",
            "output_int_register_+1",
            "output_int_register_",
        ] {
            assert_eq!(output_type(unknown), None, "{unknown:?}");
        }
        assert_eq!(input_field("input_double_register_48"), None);
        assert_eq!(input_field("actual_q"), None);
    }
}
