//! `rigserve bench rig`: a full `rigserve rig` (load, skeleton, skin, export), whole
//! process, on one mesh subdivided to several sizes, with each run's wall time and peak
//! resident memory. Each run is a fresh child process, as a user's command line is, so
//! model loading and start-up count, and the peak is that process's alone.

use super::LimitArgs;
use anyhow::{bail, Context};
use rigserve::mesh::{self, Mesh};
use serde::Serialize;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct RigArgs {
    /// The mesh to subdivide (any format `rig` reads).
    #[arg(long)]
    pub mesh: PathBuf,
    /// Midpoint subdivisions (each splits every triangle in four, about 4x the vertices).
    #[arg(long, value_delimiter = ',', default_value = "0,2,3")]
    pub levels: Vec<u32>,
    /// Runs per size; the best is reported beside the mean.
    #[arg(long, default_value_t = 3)]
    pub repeat: usize,
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub limits: LimitArgs,
    /// Passed on to each `rigserve rig` (after `--`), e.g. `-- --skin-method geometric`.
    #[arg(last = true)]
    pub rig_args: Vec<String>,
}

#[derive(Serialize)]
struct Row {
    level: u32,
    vertices: usize,
    triangles: usize,
    best_s: f64,
    mean_s: f64,
    peak_rss_mib: f64,
}

pub fn run(a: RigArgs) -> anyhow::Result<()> {
    let bytes = std::fs::read(&a.mesh).with_context(|| format!("reading {}", a.mesh.display()))?;
    let asset = mesh::load(&bytes, &a.limits.limits())
        .map_err(|e| anyhow::anyhow!("{e} [{}]", e.code()))?;
    let tmp = tempfile::tempdir()?;
    let exe = std::env::current_exe()?;
    let mut rows = Vec::new();
    for &level in &a.levels {
        let mut m = asset.mesh.clone();
        for _ in 0..level {
            m = m.subdivided();
        }
        let input = tmp.path().join(format!("level{level}.obj"));
        write_obj(&m, &input)?;
        let out = tmp.path().join(format!("level{level}.glb"));
        let mut times = Vec::new();
        let mut peak_kib = 0i64;
        for _ in 0..a.repeat.max(1) {
            let (secs, kib) = timed_child(&exe, &input, &out, &a.rig_args)?;
            times.push(secs);
            peak_kib = peak_kib.max(kib);
        }
        let row = Row {
            level,
            vertices: m.positions.len(),
            triangles: m.triangles.len(),
            best_s: times.iter().copied().fold(f64::INFINITY, f64::min),
            mean_s: times.iter().sum::<f64>() / times.len() as f64,
            peak_rss_mib: peak_kib as f64 / 1024.0,
        };
        if !a.json {
            println!(
                "{:>9} vertices {:>9} triangles | best {:.3} s, mean {:.3} s over {} | peak RSS {:.0} MiB",
                row.vertices,
                row.triangles,
                row.best_s,
                row.mean_s,
                times.len(),
                row.peak_rss_mib
            );
        }
        rows.push(row);
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    }
    Ok(())
}

/// Runs `rigserve rig INPUT --out OUT ARGS` and returns its wall time and peak RSS (KiB),
/// read from the kernel's accounting of that one child (`wait4`).
fn timed_child(
    exe: &Path,
    input: &Path,
    out: &Path,
    args: &[String],
) -> anyhow::Result<(f64, i64)> {
    let t = Instant::now();
    let child = std::process::Command::new(exe)
        .arg("rig")
        .arg(input)
        .arg("--out")
        .arg(out)
        .args(args)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()?;
    let pid = child.id() as libc::pid_t;
    let mut status = 0;
    // SAFETY: rusage is plain data the kernel fills; pid is our own unwaited child.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let got = unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
    let secs = t.elapsed().as_secs_f64();
    if got != pid {
        bail!(
            "waiting for rigserve rig: {}",
            std::io::Error::last_os_error()
        );
    }
    if !(libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0) {
        let mut err = String::new();
        if let Some(mut e) = child.stderr {
            use std::io::Read;
            let _ = e.read_to_string(&mut err);
        }
        bail!("rigserve rig {} failed: {}", input.display(), err.trim());
    }
    Ok((secs, usage.ru_maxrss))
}

fn write_obj(m: &Mesh, path: &Path) -> anyhow::Result<()> {
    let mut w = std::io::BufWriter::new(std::fs::File::create(path)?);
    for p in &m.positions {
        writeln!(w, "v {} {} {}", p.x, p.y, p.z)?;
    }
    for t in &m.triangles {
        writeln!(w, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1)?;
    }
    w.flush()?;
    Ok(())
}
