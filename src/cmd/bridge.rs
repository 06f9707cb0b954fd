//! `bowden bench bridge`: the Zenoh bridge's hop on loopback beside the plain iceoryx2 hop.

use anyhow::{Context, Result};
use bowden_bridge::bench::{bridge_bench, ipc_row, BridgeBenchOptions, HopRow};
use bowden_runtime::bench::{ipc_bench, IpcVariant, Peer};
use bowden_runtime::stats::fmt_ns;
use clap::{Args, Subcommand};
use std::path::PathBuf;

#[derive(Subcommand)]
pub enum BenchCommand {
    /// One hop over the Zenoh bridge on loopback (two bridge processes, two iceoryx2 prefixes):
    /// JointEstimate over a low-latency and a frame-capable link, and checksummed 640x480 RGBD
    /// frames at the camera's rate; JointEstimate with the export in the producer's process
    /// (only the importing bridge apart); beside the plain iceoryx2 hop to another process, in
    /// the same run, Zenoh alone and a plain TCP socket between two processes.
    /// p50/p99/p99.9/max one way.
    Bridge(BridgeArgs),
    /// The receiving process of `bench bridge`'s raw Zenoh hop (started by it).
    #[command(hide = true)]
    BridgePeer {
        #[arg(long)]
        connect: String,
        #[arg(long)]
        count: usize,
        #[arg(long, action = clap::ArgAction::Set)]
        low_latency: bool,
    },
    /// The receiving process of `bench bridge`'s plain TCP hop (started by it).
    #[command(hide = true)]
    TcpPeer {
        #[arg(long)]
        connect: String,
        #[arg(long)]
        count: usize,
    },
}

#[derive(Args, Debug)]
pub struct BridgeArgs {
    /// JointEstimate samples per link.
    #[arg(long, default_value_t = 3000)]
    samples: usize,
    /// Their rate, Hz (the camera's 30-90 fps, or faster to gather more).
    #[arg(long, default_value_t = 200.0)]
    rate_hz: f64,
    /// RGBD frames sent.
    #[arg(long, default_value_t = 300)]
    frames: usize,
    /// Their rate, frames per second.
    #[arg(long, default_value_t = 30.0)]
    fps: f64,
    /// Round trips of the plain iceoryx2 hop, per variant.
    #[arg(long, default_value_t = 5000)]
    ipc_samples: usize,
    /// Print each bridge process's run summary too (latency since origin, faults).
    #[arg(long)]
    process_summaries: bool,
    /// Print the rows as JSON on stdout instead of the table.
    #[arg(long)]
    json: bool,
    /// Also write the rows as JSON to FILE.
    #[arg(long, value_name = "FILE")]
    json_out: Option<PathBuf>,
    /// Overwrite --json-out if it exists.
    #[arg(long)]
    force: bool,
}

pub fn bench(c: BenchCommand) -> Result<()> {
    let a = match c {
        BenchCommand::Bridge(a) => a,
        BenchCommand::BridgePeer {
            connect,
            count,
            low_latency,
        } => {
            let lat = bowden_bridge::bench::raw_zenoh_peer(&connect, count, low_latency).map_err(anyhow::Error::msg)?;
            println!("{}", serde_json::to_string(&lat)?);
            return Ok(());
        }
        BenchCommand::TcpPeer { connect, count } => {
            let lat = bowden_bridge::bench::raw_tcp_peer(&connect, count).map_err(anyhow::Error::msg)?;
            println!("{}", serde_json::to_string(&lat)?);
            return Ok(());
        }
    };
    super::refuse_overwrite(a.json_out.as_slice(), a.force, "--json-out")?;
    if a.samples == 0 || a.frames < 4 || a.ipc_samples == 0 {
        anyhow::bail!("--samples and --ipc-samples must be positive, --frames at least 4");
    }
    let exe = std::env::current_exe().context("locating the bowden executable")?;
    let prefix = format!("bwbr{}", std::process::id());
    let opts = BridgeBenchOptions {
        exe: exe.clone(),
        samples: a.samples,
        rate_hz: a.rate_hz,
        frames: a.frames,
        fps: a.fps,
        prefix: prefix.clone(),
        process_summaries: a.process_summaries,
    };
    let progress = |s: &str| eprintln!("bench bridge: {s}");
    let mut rows = bridge_bench(&opts, &progress).map_err(anyhow::Error::msg)?;
    progress("the plain iceoryx2 hop (bench ipc, event-driven, another process)");
    let ipc = ipc_bench(
        &format!("{prefix}i"),
        a.ipc_samples,
        a.ipc_samples / 10,
        5,
        &Peer::Process(exe),
        &[IpcVariant::PortsSampleEvent, IpcVariant::PortsFrameVga],
        None,
    )
    .context("plain iceoryx2 hop")?;
    rows.push(ipc_row("JointCommand (240 B)", &ipc[0], a.ipc_samples as u64));
    rows.push(ipc_row("RGBD 640x480 (1.5 MB)", &ipc[1], a.ipc_samples as u64));
    let json = serde_json::to_string_pretty(&rows)?;
    if let Some(p) = &a.json_out {
        std::fs::write(p, &json).with_context(|| p.display().to_string())?;
    }
    if a.json {
        println!("{json}");
    } else {
        print!("{}", table(&rows, &a));
    }
    Ok(())
}

fn table(rows: &[HopRow], a: &BridgeArgs) -> String {
    let mut s = format!(
        "bench bridge: loopback, {} JointEstimate at {} Hz per link, {} frames at {} fps; \
         Zenoh runtime: {}\n\n\
         | stream | path | sent | delivered | corrupt | rate /s | p50 | p99 | p99.9 | max | p50 first/last quarter |\n\
         |---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|\n",
        a.samples,
        a.rate_hz,
        a.frames,
        a.fps,
        bowden_bridge::zenoh_runtime_in_effect()
    );
    for r in rows {
        let q = match (r.p50_first_quarter_ns, r.p50_last_quarter_ns) {
            (Some(f), Some(l)) => format!("{} / {}", fmt_ns(f), fmt_ns(l)),
            _ => "".into(),
        };
        s.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
            r.stream,
            r.path,
            r.sent,
            r.delivered,
            r.corrupt,
            if r.delivered_per_s > 0.0 {
                format!("{:.1}", r.delivered_per_s)
            } else {
                "".into()
            },
            fmt_ns(r.one_way.p50_ns),
            fmt_ns(r.one_way.p99_ns),
            fmt_ns(r.one_way.p999_ns),
            fmt_ns(r.one_way.max_ns),
            q
        ));
    }
    s
}
