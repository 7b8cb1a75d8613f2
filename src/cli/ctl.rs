//! `mmnormd ctl`: the control port's client.

use std::io::{BufRead, BufReader, Write};
use std::net::{SocketAddr, TcpStream, ToSocketAddrs};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use mmnormd::progress::Progress;
use serde_json::{Value, json};

#[derive(clap::Args)]
pub struct CtlArgs {
    /// The daemon's control address, HOST[:PORT] (a name such as localhost, or an IP address;
    /// PORT defaults to 7878, the daemon's `control.bind`).
    #[arg(long, default_value = "127.0.0.1:7878")]
    pub addr: String,
    /// The port's token, when it requires one.
    #[arg(long, env = "MMNORMD_TOKEN")]
    pub token: Option<String>,
    #[command(subcommand)]
    pub command: CtlCommand,
}

#[derive(clap::Subcommand)]
pub enum CtlCommand {
    /// Start a scan (one at a time; a second gets "busy").
    Scan {
        /// The scan's folder name under recording.data_dir (letters, digits, `-`, `_`, `.`)
        /// [default: scan-<unix seconds>].
        #[arg(long)]
        name: Option<String>,
        /// Raster width along the base's x, metres [default: the config's scan.width_m].
        #[arg(long, allow_negative_numbers = true)]
        width_m: Option<f64>,
        /// Raster height along the base's y, metres [default: the config's scan.height_m].
        #[arg(long, allow_negative_numbers = true)]
        height_m: Option<f64>,
        /// TCP speed along each row, metres per second [default: the config's
        /// scan.speed_m_per_s].
        #[arg(long, allow_negative_numbers = true)]
        speed_m_per_s: Option<f64>,
        /// Free text stored with the scan (what was scanned, under what).
        #[arg(long)]
        label: Option<String>,
        /// Follow the scan with a progress bar until its result.
        #[arg(long)]
        wait: bool,
    },
    /// The daemon's state.
    Status,
    /// Abort the running scan (the arm stops first).
    Abort,
    /// Stored scans and their reconstructions.
    List,
    /// Reconstruct a stored scan again.
    Reconstruct {
        /// The scan's name, as `list` prints it.
        scan: String,
    },
    /// Print events as they come, one JSON object per line, until Ctrl-C.
    Subscribe,
}

struct Connection {
    reader: BufReader<TcpStream>,
    writer: TcpStream,
    token: Option<String>,
}

/// The daemon's default control port (`control.bind` in config/lab.toml).
const DEFAULT_PORT: u16 = 7878;

/// How long a connection attempt to one address may take.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(3);

/// The addresses `text` (HOST or HOST:PORT, an IPv6 address in brackets) names, PORT defaulting
/// to [`DEFAULT_PORT`].
pub fn resolve_addr(text: &str) -> Result<Vec<SocketAddr>> {
    let with_port = if text.parse::<SocketAddr>().is_ok() {
        text.to_string()
    } else if text.parse::<std::net::IpAddr>().is_ok() {
        // A bare address; an IPv6 one needs brackets before a port.
        if text.contains(':') {
            format!("[{text}]:{DEFAULT_PORT}")
        } else {
            format!("{text}:{DEFAULT_PORT}")
        }
    } else if text.rsplit_once(':').is_some_and(|(host, port)| {
        !host.is_empty() && !port.is_empty() && port.bytes().all(|b| b.is_ascii_digit())
    }) {
        text.to_string()
    } else {
        format!("{text}:{DEFAULT_PORT}")
    };
    let addrs: Vec<SocketAddr> = with_port
        .to_socket_addrs()
        .with_context(|| format!("--addr {text:?}: not a HOST[:PORT] that resolves"))?
        .collect();
    if addrs.is_empty() {
        bail!("--addr {text:?}: resolves to no address");
    }
    Ok(addrs)
}

/// Connects to the first of `addrs` that answers; the error says what to do about the last
/// failure (start the daemon, check the address).
fn connect(addrs: &[SocketAddr]) -> Result<TcpStream> {
    let mut last = None;
    for addr in addrs {
        match TcpStream::connect_timeout(addr, CONNECT_TIMEOUT) {
            Ok(stream) => return Ok(stream),
            Err(e) => last = Some((*addr, e)),
        }
    }
    let Some((addr, e)) = last else {
        bail!("no address to connect to");
    };
    let hint = match e.kind() {
        std::io::ErrorKind::ConnectionRefused => {
            "nothing listens there: is the daemon running? Start it with `mmnormd --config \
             LAB.toml` (or `systemctl start mmnormd`), and check its control.bind"
        }
        std::io::ErrorKind::TimedOut | std::io::ErrorKind::WouldBlock => {
            "timed out: check the address and that the host is reachable"
        }
        _ => "check --addr",
    };
    bail!("connecting to mmnormd at {addr}: {e} ({hint})")
}

impl Connection {
    fn open(addrs: &[SocketAddr], token: Option<String>) -> Result<Self> {
        let stream = connect(addrs)?;
        Ok(Self {
            reader: BufReader::new(stream.try_clone()?),
            writer: stream,
            token,
        })
    }

    fn send(&mut self, mut request: Value) -> Result<()> {
        if let (Some(t), Some(map)) = (&self.token, request.as_object_mut()) {
            map.insert("token".into(), json!(t));
        }
        let mut line = request.to_string();
        line.push('\n');
        self.writer.write_all(line.as_bytes())?;
        Ok(())
    }

    fn next(&mut self) -> Result<Value> {
        let mut line = String::new();
        if self.reader.read_line(&mut line)? == 0 {
            bail!("the daemon closed the connection");
        }
        Ok(serde_json::from_str(&line)?)
    }

    /// Sends a request and returns its reply (skipping events).
    fn call(&mut self, request: Value) -> Result<Value> {
        self.send(request)?;
        loop {
            let v = self.next()?;
            if v.get("ok").is_some() {
                if v["ok"] == json!(false) {
                    bail!("{}", v["error"].as_str().unwrap_or("error"));
                }
                return Ok(v);
            }
        }
    }
}

pub fn run(args: &CtlArgs, quiet: bool) -> Result<()> {
    let addrs = resolve_addr(&args.addr)?;
    let mut c = Connection::open(&addrs, args.token.clone())?;
    let request = match &args.command {
        CtlCommand::Status => json!({"cmd": "status"}),
        CtlCommand::Abort => json!({"cmd": "abort"}),
        CtlCommand::List => json!({"cmd": "list"}),
        CtlCommand::Reconstruct { scan } => json!({"cmd": "reconstruct", "scan": scan}),
        CtlCommand::Subscribe => {
            println!("{}", c.call(json!({"cmd": "subscribe"}))?);
            loop {
                println!("{}", c.next()?);
            }
        }
        CtlCommand::Scan {
            name,
            width_m,
            height_m,
            speed_m_per_s,
            label,
            wait,
        } => {
            let scan = json!({"cmd": "scan", "name": name, "width_m": width_m,
                "height_m": height_m, "speed_m_per_s": speed_m_per_s, "label": label});
            if *wait {
                return scan_and_wait(&mut c, scan, quiet);
            }
            scan
        }
    };
    println!("{}", serde_json::to_string_pretty(&c.call(request)?)?);
    Ok(())
}

/// Subscribes, starts the scan and follows it to its result; returns the result event.
pub fn scan_and_wait_value(
    addr: SocketAddr,
    token: Option<String>,
    scan: Value,
    quiet: bool,
) -> Result<Value> {
    let mut c = Connection::open(&[addr], token)?;
    c.call(json!({"cmd": "subscribe"}))?;
    let reply = c.call(scan)?;
    let name = reply["scan"].as_str().unwrap_or_default().to_string();
    let rows = reply["rows"].as_u64().unwrap_or(0);
    let progress = Progress::new(&format!("scan {name}"), rows, quiet);
    loop {
        let e = c.next()?;
        if e.get("scan").and_then(Value::as_str) != Some(name.as_str()) {
            continue;
        }
        match e["event"].as_str() {
            Some("row") if e["accepted"] == json!(true) => progress.inc(1),
            Some("row") => progress.set_message(&format!(
                "row {} again: {}",
                e["row"].as_u64().unwrap_or(0) + 1,
                e["problem"].as_str().unwrap_or("")
            )),
            Some("stage") => progress.set_message(e["stage"].as_str().unwrap_or("")),
            Some("result") => {
                progress.finish();
                return Ok(e);
            }
            Some("error") => {
                progress.finish();
                bail!("scan {name}: {}", e["message"].as_str().unwrap_or("failed"));
            }
            _ => {}
        }
    }
}

fn scan_and_wait(c: &mut Connection, scan: Value, quiet: bool) -> Result<()> {
    let addr = c.writer.peer_addr()?;
    let result = scan_and_wait_value(addr, c.token.clone(), scan, quiet)?;
    println!("{}", serde_json::to_string_pretty(&result)?);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses_take_names_and_a_default_port() {
        let one = |t: &str| resolve_addr(t).unwrap();
        assert_eq!(
            one("127.0.0.1:9000"),
            vec!["127.0.0.1:9000".parse().unwrap()]
        );
        assert_eq!(one("127.0.0.1"), vec!["127.0.0.1:7878".parse().unwrap()]);
        assert_eq!(one("::1"), vec!["[::1]:7878".parse().unwrap()]);
        assert_eq!(one("[::1]:9000"), vec!["[::1]:9000".parse().unwrap()]);
        let local = one("localhost");
        assert!(
            local
                .iter()
                .all(|a| a.port() == 7878 && a.ip().is_loopback()),
            "{local:?}"
        );
        let local = one("localhost:9000");
        assert!(local.iter().all(|a| a.port() == 9000), "{local:?}");
        let err = resolve_addr("127.0.0.1:notaport").unwrap_err().to_string();
        assert!(err.contains("--addr \"127.0.0.1:notaport\""), "{err}");
    }

    #[test]
    fn a_refused_connection_says_to_start_the_daemon() {
        // Bind and drop: nothing listens on the port afterwards.
        let addr = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap();
        let err = connect(&[addr]).unwrap_err().to_string();
        println!("{err}");
        assert!(err.contains(&addr.to_string()), "{err}");
        assert!(err.contains("is the daemon running?"), "{err}");
        assert!(err.contains("mmnormd --config"), "{err}");
    }
}
