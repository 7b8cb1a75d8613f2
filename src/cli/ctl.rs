//! `mmnormd ctl`: the control port's client.

use std::io::{BufRead, BufReader, Write};
use std::net::{SocketAddr, TcpStream};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use mmnormd::progress::Progress;
use serde_json::{Value, json};

#[derive(clap::Args)]
pub struct CtlArgs {
    /// The daemon's control address.
    #[arg(long, default_value = "127.0.0.1:7878")]
    pub addr: SocketAddr,
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
        #[arg(long)]
        name: Option<String>,
        #[arg(long)]
        width_m: Option<f64>,
        #[arg(long)]
        height_m: Option<f64>,
        #[arg(long)]
        speed_m_per_s: Option<f64>,
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
    Reconstruct { scan: String },
    /// Print events as they come, one JSON object per line, until Ctrl-C.
    Subscribe,
}

struct Connection {
    reader: BufReader<TcpStream>,
    writer: TcpStream,
    token: Option<String>,
}

impl Connection {
    fn open(addr: SocketAddr, token: Option<String>) -> Result<Self> {
        let stream = TcpStream::connect_timeout(&addr, Duration::from_secs(3))
            .with_context(|| format!("connecting to mmnormd at {addr}"))?;
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
    let mut c = Connection::open(args.addr, args.token.clone())?;
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
    let mut c = Connection::open(addr, token)?;
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
