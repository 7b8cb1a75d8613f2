//! Shared by the simulated-lab tests: a private copy of config/sim.toml with free loopback
//! ports, a private PTY link and data directory, and a small raster.

use std::net::{SocketAddr, TcpListener, UdpSocket};
use std::path::{Path, PathBuf};

pub fn tcp_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

pub fn udp_port(ip: &str) -> u16 {
    UdpSocket::bind((ip, 0))
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// config/sim.toml with free ports, private paths, a small raster and `change` applied.
pub fn write_config(dir: &Path, change: impl FnOnce(&mut toml::Table)) -> (PathBuf, SocketAddr) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("config/sim.toml")).unwrap();
    let text = text.replace("\"../", &format!("\"{}/", root.display()));
    let mut t: toml::Table = toml::from_str(&text).unwrap();
    let control = SocketAddr::from(([127, 0, 0, 1], tcp_port()));
    let set = |t: &mut toml::Table, section: &str, key: &str, v: toml::Value| {
        t.entry(section)
            .or_insert_with(|| toml::Value::Table(Default::default()))
            .as_table_mut()
            .unwrap()
            .insert(key.into(), v);
    };
    let link = dir.join("radar-cli").display().to_string();
    set(&mut t, "control", "bind", control.to_string().into());
    set(
        &mut t,
        "robot",
        "dashboard_port",
        i64::from(tcp_port()).into(),
    );
    set(&mut t, "robot", "script_port", i64::from(tcp_port()).into());
    set(&mut t, "robot", "rtde_port", i64::from(tcp_port()).into());
    set(
        &mut t,
        "dca1000",
        "host_config_port",
        i64::from(udp_port("127.0.0.1")).into(),
    );
    set(
        &mut t,
        "dca1000",
        "host_data_port",
        i64::from(udp_port("127.0.0.1")).into(),
    );
    set(
        &mut t,
        "dca1000",
        "config_port",
        i64::from(udp_port("127.0.0.2")).into(),
    );
    set(
        &mut t,
        "sim",
        "board_data_port",
        i64::from(udp_port("127.0.0.2")).into(),
    );
    set(&mut t, "sim", "radar_link", link.clone().into());
    set(&mut t, "radar", "serial_port", link.into());
    let data = dir.join("captures").display().to_string();
    set(&mut t, "recording", "data_dir", data.into());
    // Three rows of 6 cm: a few seconds of scanning.
    set(&mut t, "scan", "width_m", 0.06.into());
    set(&mut t, "scan", "height_m", 0.0116.into());
    change(&mut t);
    let path = dir.join("lab.toml");
    std::fs::write(&path, toml::to_string(&t).unwrap()).unwrap();
    (path, control)
}
