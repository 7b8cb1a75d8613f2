//! Shared by the simulated-lab tests: a private copy of config/sim.toml with free loopback
//! ports, a private PTY link and data directory, and a small raster.

use std::net::{SocketAddr, TcpListener, UdpSocket};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::sync::atomic::{AtomicU32, Ordering};

/// A port that the daemon will bind later, chosen so that nothing else takes it meanwhile:
/// below the kernel's ephemeral range (the outgoing connections of tests running beside this
/// one draw their source ports from that range, so a port asked of the kernel with bind(0)
/// and released can be taken by one of them before the daemon binds it), distinct within this
/// process, and free when handed out (`bindable`).
fn reserved_port(bindable: impl Fn(u16) -> bool) -> u16 {
    static NEXT: AtomicU32 = AtomicU32::new(0);
    static EPHEMERAL_LOW: OnceLock<u32> = OnceLock::new();
    let ephemeral_low = *EPHEMERAL_LOW.get_or_init(|| {
        std::fs::read_to_string("/proc/sys/net/ipv4/ip_local_port_range")
            .ok()
            .and_then(|t| t.split_whitespace().next()?.parse::<u32>().ok())
            .unwrap_or(32768)
    });
    let (low, span) = (10_000u32, ephemeral_low.saturating_sub(10_000).max(1000));
    // Different test binaries (one after another) start at different places.
    let start = std::process::id().wrapping_mul(2_654_435_761) % span;
    loop {
        let k = NEXT.fetch_add(1, Ordering::Relaxed);
        let port = (low + (start + k) % span) as u16;
        if bindable(port) {
            return port;
        }
    }
}

pub fn tcp_port() -> u16 {
    reserved_port(|p| TcpListener::bind(("127.0.0.1", p)).is_ok())
}

pub fn udp_port(ip: &str) -> u16 {
    reserved_port(|p| UdpSocket::bind((ip, p)).is_ok())
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
    for key in ["dashboard_port", "script_port", "rtde_port"] {
        set(&mut t, "robot", key, i64::from(tcp_port()).into());
    }
    // The host's sockets on 127.0.0.1, the simulated board's on 127.0.0.2.
    for (section, key, ip) in [
        ("dca1000", "host_config_port", "127.0.0.1"),
        ("dca1000", "host_data_port", "127.0.0.1"),
        ("dca1000", "config_port", "127.0.0.2"),
        ("sim", "board_data_port", "127.0.0.2"),
    ] {
        set(&mut t, section, key, i64::from(udp_port(ip)).into());
    }
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
