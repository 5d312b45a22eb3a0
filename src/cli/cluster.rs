//! `geostride split`, `segment`, `merge` and `slurm`: one run across a cluster's batch engine,
//! giving what `geostride run` gives.

use std::path::{Path, PathBuf};

use anyhow::anyhow;

use super::bad_input;
use geostride::cache::build_id;
use geostride::pipeline::cluster::{
    FORMAT, MANIFEST, Manifest, SlurmOptions, index_from, segments, slurm_scripts,
};
use geostride::pipeline::project::{Loaded, load};
use geostride::pipeline::run::{
    ChunkMode, RunError, chunk_list, plan_chunks, run_segment, run_with,
};

#[derive(clap::Args)]
pub struct SplitArgs {
    /// The project file (TOML), as for `geostride run`
    project: PathBuf,
    /// How many segments (tasks of the job array)
    #[arg(long, value_name = "N")]
    segments: usize,
    /// The run's folder: the manifest, the segments' results and, after `merge`, the outputs
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// No progress bars
    #[arg(short, long)]
    quiet: bool,
}

#[derive(clap::Args)]
pub struct SegmentArgs {
    /// The folder `geostride split` made
    dir: PathBuf,
    /// Which segment (from 0) [default: the batch engine's array index: SLURM_ARRAY_TASK_ID,
    /// JOB_COMPLETION_INDEX or AWS_BATCH_JOB_ARRAY_INDEX]
    #[arg(long, value_name = "I")]
    index: Option<usize>,
    /// No progress bars
    #[arg(short, long)]
    quiet: bool,
}

#[derive(clap::Args)]
pub struct MergeArgs {
    /// The folder `geostride split` made, every segment done
    dir: PathBuf,
    /// No progress bars
    #[arg(short, long)]
    quiet: bool,
}

#[derive(clap::Args)]
pub struct SlurmArgs {
    /// The project file (TOML), as for `geostride run`
    project: PathBuf,
    /// How many segments (tasks of the job array)
    #[arg(long, value_name = "N")]
    segments: usize,
    /// The run's folder (on a file system every node sees)
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Submit the array and the merge (`sbatch`); otherwise only write the scripts
    #[arg(long)]
    submit: bool,
    /// The partition (queue)
    #[arg(long)]
    partition: Option<String>,
    /// Time limit of a segment
    #[arg(long, default_value = "4:00:00")]
    time: String,
    /// Time limit of the merge
    #[arg(long, default_value = "2:00:00")]
    merge_time: String,
    /// Memory of a segment
    #[arg(long, default_value = "8G")]
    mem: String,
    /// Memory of the merge
    #[arg(long, default_value = "16G")]
    merge_mem: String,
    /// CPUs of each task
    #[arg(long, default_value_t = 2)]
    cpus: u32,
    /// An extra #SBATCH option for both scripts (repeatable), e.g. --sbatch=--account=crowd
    #[arg(long = "sbatch", value_name = "OPTION")]
    extra: Vec<String>,
    /// No progress bars
    #[arg(short, long)]
    quiet: bool,
}

fn run_error(e: RunError) -> anyhow::Error {
    if e.is_input() {
        bad_input(anyhow!(e))
    } else {
        anyhow!(e)
    }
}

fn sha256_file(path: &Path) -> anyhow::Result<String> {
    use sha2::Digest as _;
    let bytes = std::fs::read(path).map_err(|e| bad_input(anyhow!("{}: {e}", path.display())))?;
    Ok(sha2::Sha256::digest(&bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect())
}

/// The manifest's project, loaded and checked unchanged since the split.
fn load_split(dir: &Path) -> anyhow::Result<(Manifest, Loaded)> {
    let m = Manifest::read(dir).map_err(|e| bad_input(anyhow!(e)))?;
    let sum = sha256_file(&m.project)?;
    if sum != m.project_sha256 {
        return Err(bad_input(anyhow!(
            "{}: changed since it was split into {} (the segments would not match): split again",
            m.project.display(),
            dir.display()
        )));
    }
    if m.geostride != build_id() {
        return Err(bad_input(anyhow!(
            "{} was split by geostride {}, this is {}: every task must run the same build (split again)",
            dir.display(),
            m.geostride,
            build_id()
        )));
    }
    let mut l = load(&m.project).map_err(bad_input)?;
    // The video was hashed once, by split: a file whose size or time changed is hashed again,
    // and refused if its content is not the one split.
    geostride::pipeline::run::check_known_inputs(&l, &m.plan.inputs, dir).map_err(run_error)?;
    l.known_inputs = m.plan.inputs.clone();
    Ok((m, l))
}

/// Splits and writes the manifest; the manifest. A split refused leaves no folder it made.
fn split(project: &Path, n: usize, out: &Path, quiet: bool) -> anyhow::Result<Manifest> {
    if n == 0 {
        return Err(bad_input(anyhow!(
            "--segments 0: expected at least 1 segment"
        )));
    }
    let existed = out.exists();
    let made = split_into(project, n, out, quiet);
    if made.is_err() && !existed && out.is_dir() {
        let _ = std::fs::remove_dir_all(out);
    }
    made
}

fn split_into(project: &Path, n: usize, out: &Path, quiet: bool) -> anyhow::Result<Manifest> {
    let project = std::fs::canonicalize(project)
        .map_err(|e| bad_input(anyhow!("{}: {e}", project.display())))?;
    // Loaded from the path the segments load it from: the inputs' paths (and the checksums
    // known for them) are the same.
    let l = load(&project).map_err(bad_input)?;
    let plan = plan_chunks(&l, out, &super::StageBars { quiet }).map_err(run_error)?;
    let chunks = plan.grid.chunks();
    let segs = segments(chunks, n).ok_or_else(|| {
        bad_input(anyhow!(
            "{n} segment(s) asked for, but the video's {} frames make {chunks} chunk(s) of {} s (video.chunk_s): ask for at most {chunks}, or set a shorter video.chunk_s in {}",
            plan.grid.frames,
            l.project.video.chunk_s,
            project.display()
        ))
    })?;
    let m = Manifest {
        format: FORMAT.into(),
        project_sha256: sha256_file(&project)?,
        project,
        geostride: build_id().into(),
        plan,
        segments: segs,
    };
    let json = serde_json::to_string_pretty(&m)?;
    geostride::io::write_atomic(&out.join(MANIFEST), json.as_bytes())?;
    Ok(m)
}

fn describe(m: &Manifest, dir: &Path) {
    let g = &m.plan.grid;
    println!(
        "Split {} into {} segment(s) in {}: {} frames, {} chunk(s) of {} frames (+{} overlap){}",
        m.project.display(),
        m.segments.len(),
        dir.display(),
        g.frames,
        g.chunks(),
        g.chunk_frames,
        g.overlap_frames,
        if m.plan.palette {
            ", the colour palette learnt"
        } else {
            ""
        }
    );
    for (i, r) in m.segments.iter().enumerate() {
        let done = r.clone().filter(|c| m.plan.done.contains(c)).count();
        println!(
            "  segment {i}: chunks {}..{} (frames {}..{}){}",
            r.start,
            r.end,
            g.own(r.start).start,
            g.own(r.end - 1).end,
            if done > 0 {
                format!(", {done} chunk(s) done already")
            } else {
                String::new()
            }
        );
    }
}

pub fn run_split(a: SplitArgs) -> anyhow::Result<()> {
    let m = split(&a.project, a.segments, &a.out, a.quiet)?;
    describe(&m, &a.out);
    println!(
        "Next: geostride segment {d} --index I for I in 0..{n} (anywhere, in any order), then geostride merge {d}",
        d = a.out.display(),
        n = m.segments.len()
    );
    Ok(())
}

pub fn run_segment_cmd(a: SegmentArgs) -> anyhow::Result<()> {
    let (m, l) = load_split(&a.dir)?;
    let i = match a.index {
        Some(i) => i,
        None => index_from(|v| std::env::var(v).ok()).map_err(|e| bad_input(anyhow!(e)))?,
    };
    let Some(chunks) = m.segments.get(i).cloned() else {
        return Err(bad_input(anyhow!(
            "segment {i} asked for; {} has segments 0 to {}",
            a.dir.display(),
            m.segments.len().saturating_sub(1)
        )));
    };
    let done =
        run_segment(&l, &a.dir, &super::StageBars { quiet: a.quiet }, chunks).map_err(run_error)?;
    println!(
        "Segment {i} of {}: chunks {}..{} ({} frames): {} computed, {} done already, in {:.1} s",
        m.segments.len(),
        done.chunks.start,
        done.chunks.end,
        done.frames,
        done.computed,
        done.reused,
        done.seconds
    );
    Ok(())
}

pub fn run_merge(a: MergeArgs) -> anyhow::Result<()> {
    let (m, l) = load_split(&a.dir)?;
    let report = match run_with(
        &l,
        &a.dir,
        &super::StageBars { quiet: a.quiet },
        &ChunkMode::None,
    ) {
        Ok(r) => r,
        Err(RunError::MissingChunks(chunks)) => {
            let segs = m.segments_of(&chunks);
            return Err(anyhow!(
                "{}: segment(s) {} not done (chunks {} missing, or made from other inputs or by another build): run them again (geostride segment {} --index I, or resubmit the job script: segments done are not redone), then merge",
                a.dir.display(),
                segs.iter()
                    .map(|s| s.to_string())
                    .collect::<Vec<_>>()
                    .join(", "),
                chunk_list(&chunks),
                a.dir.display()
            ));
        }
        Err(e) => return Err(run_error(e)),
    };
    println!(
        "Merged {} segment(s) of {} into {}",
        m.segments.len(),
        report.project,
        a.dir.display()
    );
    super::run::print_stages(&report);
    for o in &report.outputs {
        println!("Written: {}", a.dir.join(o).display());
    }
    Ok(())
}

pub fn run_slurm(a: SlurmArgs) -> anyhow::Result<()> {
    let opts = SlurmOptions {
        partition: a.partition.clone(),
        time: a.time.clone(),
        merge_time: a.merge_time.clone(),
        mem: a.mem.clone(),
        merge_mem: a.merge_mem.clone(),
        cpus: a.cpus,
        extra: a.extra.clone(),
    };
    // Before the split (which hashes the video): nothing is written for options Slurm would
    // misread.
    opts.check()
        .map_err(|(flag, message)| bad_input(anyhow!("{flag} {message}")))?;
    if a.out
        .to_str()
        .is_none_or(|s| s.chars().any(char::is_control))
    {
        return Err(bad_input(anyhow!(
            "--out {}: a Slurm script cannot name this folder (a control character, or not UTF-8); choose another",
            a.out.display().to_string().escape_debug()
        )));
    }
    let m = split(&a.project, a.segments, &a.out, a.quiet)?;
    describe(&m, &a.out);
    let dir = std::fs::canonicalize(&a.out)?;
    let exe = std::env::current_exe()?;
    let (seg, merge) =
        slurm_scripts(&exe, &dir, m.segments.len(), &opts).map_err(|e| bad_input(anyhow!(e)))?;
    let sdir = dir.join("slurm");
    std::fs::create_dir_all(&sdir)?;
    geostride::io::remove_stale_temps(&sdir)?;
    let (seg_path, merge_path) = (sdir.join("segments.sbatch"), sdir.join("merge.sbatch"));
    geostride::io::write_atomic(&seg_path, seg.as_bytes())?;
    geostride::io::write_atomic(&merge_path, merge.as_bytes())?;
    let submit = format!(
        "#!/bin/bash\n# Submits the segments as a job array and the merge after all of them.\nset -euo pipefail\narray=$(sbatch --parsable {})\narray=${{array%%;*}}\nsbatch --parsable --dependency=afterok:$array {}\n",
        geostride::pipeline::cluster::shell_quote(&seg_path.display().to_string()),
        geostride::pipeline::cluster::shell_quote(&merge_path.display().to_string())
    );
    let submit_path = sdir.join("submit.sh");
    geostride::io::write_atomic(&submit_path, submit.as_bytes())?;
    println!("Written: {}", seg_path.display());
    println!("Written: {}", merge_path.display());
    println!("Written: {}", submit_path.display());
    if !a.submit {
        println!("Submit with: bash {}", submit_path.display());
        return Ok(());
    }
    let sbatch = |args: &[&str]| -> anyhow::Result<String> {
        let out = std::process::Command::new("sbatch")
            .args(args)
            .output()
            .map_err(|e| anyhow!("sbatch: {e} (is Slurm installed here, and on the PATH?)"))?;
        if !out.status.success() {
            return Err(anyhow!(
                "sbatch {}: {}",
                args.join(" "),
                String::from_utf8_lossy(&out.stderr).trim()
            ));
        }
        let id = String::from_utf8_lossy(&out.stdout).trim().to_string();
        Ok(id.split(';').next().unwrap_or_default().to_string())
    };
    let seg_s = seg_path.display().to_string();
    let array = sbatch(&["--parsable", &seg_s])?;
    let dep = format!("--dependency=afterok:{array}");
    let merge_s = merge_path.display().to_string();
    let merge_id = sbatch(&["--parsable", &dep, &merge_s])?;
    println!(
        "Submitted: segments as job array {array}, merge as job {merge_id} (after every segment)"
    );
    println!(
        "Logs: {}; outputs in {} once job {merge_id} ends",
        sdir.display(),
        dir.display()
    );
    Ok(())
}
