//! Checkpoints: a process's full state at a step, on disk, so that a run
//! killed at minute 14 continues from its last checkpoint instead of
//! starting over (docs/RELIABILITY.md, "Resume").
//!
//! A checkpoint holds the driver's loop state ([`DriverState`]), the
//! exchange's position when coupled ([`ExchangeState`]) and the solver's
//! own bytes ([`crate::driver::Solver::checkpoint`]: its state and what its
//! summary gathers). A run continued from it ends in the same state, bit
//! for bit, as the run never interrupted: checkpoints only read the state.
//!
//! Files are `DIR/checkpoints/<process>-<step>.ckpt`:
//!
//! ```text
//! b"SGFCKPT2"   magic
//! u64 LE        length of the header
//! header        bincode (standard) of CheckpointHeader
//! solver        the solver's bytes, streamed (no copy of its state in memory)
//! u64 LE        length of the solver's bytes
//! u64 LE        hash of header and solver bytes (StreamHash)
//! ```
//!
//! Written atomically: into `<name>.partial`, synced, renamed, the folder
//! synced; a process killed while writing one leaves the previous
//! checkpoints as they were and a `.partial` file that is ignored. The
//! newest [`KEEP`] of a process are kept.

use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

const MAGIC: &[u8; 8] = b"SGFCKPT2";

/// Checkpoints kept per process: the newest, and the one before it in case
/// the newest is found damaged.
pub const KEEP: usize = 2;

/// Encodes `value` (bincode, standard config) into a checkpoint's solver part.
pub fn encode_into<T: Serialize>(value: &T, out: &mut dyn Write) -> std::io::Result<()> {
    let mut out = out;
    bincode::serde::encode_into_std_write(value, &mut out, bincode::config::standard())
        .map(|_| ())
        .map_err(std::io::Error::other)
}

/// The folder of a run's checkpoints.
pub fn folder(out_dir: &Path) -> PathBuf {
    out_dir.join("checkpoints")
}

/// The run loop's own state at a checkpoint ([`crate::driver::drive`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DriverState {
    /// The solver's step count.
    pub steps: u64,
    /// Simulated time, s.
    pub time: f64,
    /// The last step a frame was recorded at.
    pub last_recorded: u64,
    /// The last step a state was recorded at.
    pub last_state: Option<u64>,
    /// Recorded frames in a row at rest.
    pub frames_at_rest: u32,
    /// Whether the mass has moved yet (rest only counts after).
    pub has_moved: bool,
}

/// The exchange's position at a checkpoint ([`crate::coupled::Exchange`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ExchangeState {
    /// Index of the next exchange.
    pub next: u64,
    /// Index and time, s, of the last message received.
    pub last_exchange: u64,
    pub last_time: f64,
    /// Exchanges completed.
    pub exchanges: u64,
}

/// The part of a checkpoint file before the solver's bytes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct CheckpointHeader {
    process: String,
    scene_hash: u64,
    driver: DriverState,
    exchange: Option<ExchangeState>,
}

/// What a checkpoint file holds.
#[derive(Debug, Clone, PartialEq)]
pub struct CheckpointFile {
    /// The process that wrote it ("dem_proc").
    pub process: String,
    /// [`scene_hash`] of the scene it ran.
    pub scene_hash: u64,
    pub driver: DriverState,
    pub exchange: Option<ExchangeState>,
    /// The solver's own bytes.
    pub solver: Vec<u8>,
}

impl CheckpointFile {
    /// The line a process logs when it continues from this checkpoint,
    /// read from `path`.
    pub fn resumed_line(&self, path: &std::path::Path) -> String {
        format!("resumed from {} (t = {:.5} s, step {})", path.display(), self.driver.time, self.driver.steps)
    }
}

/// Why a checkpoint cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    #[error("cannot write checkpoint {path}: {source} (is the disk full? set output.checkpoint_interval larger, or free space)")]
    Write { path: PathBuf, source: std::io::Error },
    #[error("cannot read checkpoint {path}: {source}")]
    Read { path: PathBuf, source: std::io::Error },
    #[error("{path} is not a usable checkpoint: {why}")]
    Damaged { path: PathBuf, why: String },
    #[error("{path} was written by {found}, not {wanted}")]
    WrongProcess { path: PathBuf, found: String, wanted: String },
    #[error("{path} is of a different scene: a run resumes only under the scene it started with (its [output] table may change)")]
    WrongScene { path: PathBuf },
}

/// A hash of the scene's physics: its TOML with the `[output]` table left
/// out, so that a resumed run may record differently or run longer, but
/// not continue under other physics.
pub fn scene_hash(scene: &schemas::Scene) -> u64 {
    let mut table: toml::Table = scene.to_toml().parse().expect("a scene's TOML parses");
    table.remove("output");
    check_hash(table.to_string().as_bytes())
}

/// A 64-bit hash of `bytes` ([`StreamHash`] over them).
pub fn check_hash(bytes: &[u8]) -> u64 {
    let mut h = StreamHash::default();
    h.update(bytes);
    h.finish()
}

/// FNV-1a over 8-byte words, fed in pieces of any length, the length mixed
/// in at the end: to tell a damaged file (~1 GB/s), not to resist an adversary.
#[derive(Debug, Clone)]
pub struct StreamHash {
    h: u64,
    pending: [u8; 8],
    pending_len: usize,
    len: u64,
}

impl Default for StreamHash {
    fn default() -> Self {
        Self { h: 0xcbf2_9ce4_8422_2325, pending: [0; 8], pending_len: 0, len: 0 }
    }
}

impl StreamHash {
    const PRIME: u64 = 0x0000_0100_0000_01b3;

    fn word(&mut self, w: u64) {
        self.h = (self.h ^ w).wrapping_mul(Self::PRIME);
        self.h ^= self.h >> 29;
    }

    pub fn update(&mut self, mut bytes: &[u8]) {
        self.len += bytes.len() as u64;
        if self.pending_len > 0 {
            let take = (8 - self.pending_len).min(bytes.len());
            self.pending[self.pending_len..self.pending_len + take].copy_from_slice(&bytes[..take]);
            self.pending_len += take;
            bytes = &bytes[take..];
            if self.pending_len < 8 {
                return;
            }
            self.word(u64::from_le_bytes(self.pending));
            self.pending_len = 0;
        }
        let mut words = bytes.chunks_exact(8);
        for w in &mut words {
            self.word(u64::from_le_bytes(w.try_into().expect("8 bytes")));
        }
        let tail = words.remainder();
        self.pending[..tail.len()].copy_from_slice(tail);
        self.pending_len = tail.len();
    }

    pub fn finish(&self) -> u64 {
        let mut h = self.h;
        for &b in &self.pending[..self.pending_len] {
            h = (h ^ b as u64).wrapping_mul(Self::PRIME);
        }
        (h ^ self.len).wrapping_mul(Self::PRIME)
    }
}

/// A writer that hashes and counts what goes through it.
struct Hashing<W> {
    inner: W,
    hash: StreamHash,
}

impl<W: Write> Write for Hashing<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.hash.update(&buf[..n]);
        Ok(n)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

/// Writes a process's checkpoints into a run's folder.
#[derive(Debug, Clone)]
pub struct CheckpointWriter {
    dir: PathBuf,
    process: &'static str,
    scene_hash: u64,
    /// Checkpoints written by this writer.
    pub written: u64,
    /// Bytes of the last one.
    pub last_bytes: u64,
    /// Wall seconds spent writing.
    pub seconds: f64,
}

impl CheckpointWriter {
    /// Checkpoints of `process` under `out_dir/checkpoints`.
    pub fn new(out_dir: &Path, process: &'static str, scene: &schemas::Scene) -> Result<Self, CheckpointError> {
        let dir = folder(out_dir);
        std::fs::create_dir_all(&dir).map_err(|source| CheckpointError::Write { path: dir.clone(), source })?;
        Ok(Self { dir, process, scene_hash: scene_hash(scene), written: 0, last_bytes: 0, seconds: 0.0 })
    }

    /// Writes one atomically, the solver's part streamed by `solver`, then
    /// removes this process's older ones beyond [`KEEP`].
    pub fn write(
        &mut self,
        driver: DriverState,
        exchange: Option<ExchangeState>,
        solver: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
    ) -> Result<PathBuf, CheckpointError> {
        let started = std::time::Instant::now();
        let header =
            CheckpointHeader { process: self.process.to_string(), scene_hash: self.scene_hash, driver, exchange };
        let header = bincode::serde::encode_to_vec(&header, bincode::config::standard()).expect("a header encodes");
        let path = self.dir.join(format!("{}-{:014}.ckpt", self.process, driver.steps));
        let partial = path.with_extension("ckpt.partial");
        let werr = |source| CheckpointError::Write { path: path.clone(), source };
        let mut file = File::create(&partial).map_err(werr)?;
        file.write_all(MAGIC).map_err(werr)?;
        file.write_all(&(header.len() as u64).to_le_bytes()).map_err(werr)?;
        // Buffered before the hash: the solver's many small writes reach
        // the hash and the file in large pieces.
        let mut out = std::io::BufWriter::with_capacity(8 << 20, Hashing { inner: file, hash: StreamHash::default() });
        out.write_all(&header).map_err(werr)?;
        solver(&mut out).map_err(werr)?;
        let Hashing { inner: mut file, hash } = out.into_inner().map_err(|e| werr(e.into_error()))?;
        let solver_len = hash.len - header.len() as u64;
        file.write_all(&solver_len.to_le_bytes()).map_err(werr)?;
        file.write_all(&hash.finish().to_le_bytes()).map_err(werr)?;
        file.sync_all().map_err(werr)?;
        drop(file);
        std::fs::rename(&partial, &path).map_err(werr)?;
        // The rename itself is durable only once the folder is synced.
        if let Ok(d) = File::open(&self.dir) {
            let _ = d.sync_all();
        }
        for old in list(&self.dir, self.process).into_iter().rev().skip(KEEP) {
            let _ = std::fs::remove_file(old.1);
        }
        self.written += 1;
        self.last_bytes = 32 + header.len() as u64 + solver_len;
        self.seconds += started.elapsed().as_secs_f64();
        Ok(path)
    }
}

/// The checkpoint files of `process` in `dir`, by step, oldest first
/// (names only; [`read`] checks the content).
pub fn list(dir: &Path, process: &str) -> Vec<(u64, PathBuf)> {
    let prefix = format!("{process}-");
    let mut found: Vec<(u64, PathBuf)> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().into_string().ok()?;
            let step = name.strip_prefix(&prefix)?.strip_suffix(".ckpt")?.parse().ok()?;
            Some((step, e.path()))
        })
        .collect();
    found.sort();
    found
}

/// Reads and checks a checkpoint of `process` for `scene`.
pub fn read(path: &Path, process: &str, scene: &schemas::Scene) -> Result<CheckpointFile, CheckpointError> {
    let file = read_unchecked(path)?;
    if file.process != process {
        return Err(CheckpointError::WrongProcess {
            path: path.to_path_buf(),
            found: file.process,
            wanted: process.to_string(),
        });
    }
    if file.scene_hash != scene_hash(scene) {
        return Err(CheckpointError::WrongScene { path: path.to_path_buf() });
    }
    Ok(file)
}

/// Reads `process`'s checkpoint for `scene` and decodes its solver part
/// (bincode, standard config) as `T`; `what` names it in the error ("its
/// lattice") when it does not decode (another version wrote it).
pub fn read_solver<T: serde::de::DeserializeOwned>(
    path: &Path,
    process: &str,
    scene: &schemas::Scene,
    what: &str,
) -> Result<(CheckpointFile, T), CheckpointError> {
    decode_solver(read(path, process, scene)?, path, what)
}

/// Decodes the solver part of `file`, read from `path` by [`read`] (a
/// caller that looks into the file before decoding reads it once);
/// `what` as in [`read_solver`].
pub fn decode_solver<T: serde::de::DeserializeOwned>(
    file: CheckpointFile,
    path: &Path,
    what: &str,
) -> Result<(CheckpointFile, T), CheckpointError> {
    let solver =
        bincode::serde::decode_from_slice(&file.solver, bincode::config::standard()).map(|(c, _)| c).map_err(|e| {
            CheckpointError::Damaged {
                path: path.to_path_buf(),
                why: format!(
                    "{what} does not decode ({e}): written by another version of {}? A checkpoint resumes only in the version that wrote it: start the run again without --resume",
                    file.process
                ),
            }
        })?;
    Ok((file, solver))
}

/// Reads a checkpoint and checks its framing and hash only.
pub fn read_unchecked(path: &Path) -> Result<CheckpointFile, CheckpointError> {
    let bytes = std::fs::read(path).map_err(|source| CheckpointError::Read { path: path.to_path_buf(), source })?;
    decode(bytes).map_err(|why| CheckpointError::Damaged { path: path.to_path_buf(), why })
}

/// Decodes the bytes of a checkpoint file, checking magic, lengths and hash.
pub fn decode(mut bytes: Vec<u8>) -> Result<CheckpointFile, String> {
    let word = |at: usize| u64::from_le_bytes(bytes[at..at + 8].try_into().expect("8 bytes"));
    if bytes.len() < 32 || &bytes[..8] != MAGIC {
        return Err("no checkpoint header (not a checkpoint of this version, or cut before its first bytes)".into());
    }
    let header_len = word(8);
    let solver_len = word(bytes.len() - 16);
    let expected = header_len.checked_add(solver_len).and_then(|n| n.checked_add(32));
    if expected != Some(bytes.len() as u64) {
        return Err(format!(
            "{} bytes where its lengths announce another size (cut short while written?)",
            bytes.len()
        ));
    }
    let body = &bytes[16..bytes.len() - 16];
    if check_hash(body) != word(bytes.len() - 8) {
        return Err("its content does not match its hash (damaged on disk)".into());
    }
    let header: CheckpointHeader =
        bincode::serde::decode_from_slice(&body[..header_len as usize], bincode::config::standard())
            .map(|(h, _)| h)
            .map_err(|e| format!("its header does not decode ({e})"))?;
    // The solver's bytes in place (a lattice's are gigabytes: no second copy).
    bytes.truncate(bytes.len() - 16);
    bytes.drain(..16 + header_len as usize);
    Ok(CheckpointFile {
        process: header.process,
        scene_hash: header.scene_hash,
        driver: header.driver,
        exchange: header.exchange,
        solver: bytes,
    })
}

/// The newest usable checkpoint of each of `processes` at one and the same
/// moment (the same exchange when coupled, else the same step time), with
/// why newer ones were passed over. None when there is no common one.
pub fn latest_common(
    dir: &Path,
    processes: &[&str],
    scene: &schemas::Scene,
) -> (Option<Vec<(PathBuf, CheckpointFile)>>, Vec<String>) {
    let mut skipped = Vec::new();
    let mut usable: Vec<Vec<(PathBuf, CheckpointFile)>> = Vec::new();
    for p in processes {
        let mut ok = Vec::new();
        for (_, path) in list(dir, p).into_iter().rev() {
            match read(&path, p, scene) {
                Ok(f) => ok.push((path, f)),
                Err(e) => skipped.push(e.to_string()),
            }
        }
        usable.push(ok);
    }
    let moment = |f: &CheckpointFile| match f.exchange {
        Some(x) => (1u8, x.next as i64),
        None => (0u8, (f.driver.time * 1e9).round() as i64),
    };
    let Some(first) = usable.first() else { return (None, skipped) };
    for (path, file) in first {
        let m = moment(file);
        let mut set = vec![(path.clone(), file.clone())];
        for others in &usable[1..] {
            match others.iter().find(|(_, f)| moment(f) == m) {
                Some((p, f)) => set.push((p.clone(), f.clone())),
                None => break,
            }
        }
        if set.len() == processes.len() {
            return (Some(set), skipped);
        }
    }
    (None, skipped)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene() -> schemas::Scene {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/validation/minimal_dry_column.toml");
        schemas::Scene::load(&path, &[]).expect("scene loads")
    }

    fn driver(steps: u64) -> DriverState {
        DriverState {
            steps,
            time: steps as f64 * 1e-5,
            last_recorded: steps,
            last_state: None,
            frames_at_rest: 0,
            has_moved: true,
        }
    }

    #[test]
    fn the_hash_of_pieces_is_the_hash_of_the_whole() {
        let bytes: Vec<u8> = (0..1000u32).map(|i| (i * 7 % 251) as u8).collect();
        let mut h = StreamHash::default();
        for piece in [&bytes[..3], &bytes[3..11], &bytes[11..12], &bytes[12..500], &bytes[500..]] {
            h.update(piece);
        }
        assert_eq!(h.finish(), check_hash(&bytes));
        assert_ne!(check_hash(&bytes[..999]), check_hash(&bytes));
    }

    #[test]
    fn written_checkpoints_read_back_and_only_the_newest_are_kept() {
        let dir = tempdir("kept");
        let scene = scene();
        let mut w = CheckpointWriter::new(&dir, "dem_proc", &scene).unwrap();
        for steps in [100, 200, 300] {
            w.write(driver(steps), None, |o| o.write_all(&[steps as u8; 1000])).unwrap();
        }
        let files = list(&folder(&dir), "dem_proc");
        assert_eq!(files.iter().map(|f| f.0).collect::<Vec<_>>(), vec![200, 300]);
        let back = read(&files[1].1, "dem_proc", &scene).unwrap();
        assert_eq!(back.driver, driver(300));
        assert_eq!(back.solver, vec![44u8; 1000]);
        assert!(matches!(read(&files[1].1, "lbm_proc", &scene), Err(CheckpointError::WrongProcess { .. })));
    }

    #[test]
    fn a_cut_or_flipped_file_is_refused_and_the_previous_one_used() {
        let dir = tempdir("damaged");
        let scene = scene();
        let mut w = CheckpointWriter::new(&dir, "mpm_proc", &scene).unwrap();
        w.write(driver(10), None, |o| o.write_all(&vec![1; 4096])).unwrap();
        let newest = w.write(driver(20), None, |o| o.write_all(&vec![2; 4096])).unwrap();
        let bytes = std::fs::read(&newest).unwrap();
        // A kill while writing leaves a .partial file; a crash of the disk a cut one.
        std::fs::write(folder(&dir).join("mpm_proc-00000000000030.ckpt.partial"), &bytes[..100]).unwrap();
        std::fs::write(&newest, &bytes[..bytes.len() - 1]).unwrap();
        let (set, skipped) = latest_common(&folder(&dir), &["mpm_proc"], &scene);
        assert_eq!(set.unwrap()[0].1.driver.steps, 10);
        assert!(skipped[0].contains("cut short"), "{skipped:?}");
        let mut flipped = bytes.clone();
        flipped[200] ^= 1;
        std::fs::write(&newest, &flipped).unwrap();
        let (_, skipped) = latest_common(&folder(&dir), &["mpm_proc"], &scene);
        assert!(skipped[0].contains("hash"), "{skipped:?}");
    }

    #[test]
    fn a_changed_scene_is_refused_but_its_output_may_change() {
        let dir = tempdir("scene");
        let scene = scene();
        let mut w = CheckpointWriter::new(&dir, "dem_proc", &scene).unwrap();
        let path = w.write(driver(5), None, |_| Ok(())).unwrap();
        let path_to = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/validation/minimal_dry_column.toml");
        let longer = schemas::Scene::load(&path_to, &["output.end_time=9.0".into()]).unwrap();
        assert!(read(&path, "dem_proc", &longer).is_ok());
        let other = schemas::Scene::load(&path_to, &["domain.gravity=[0.0, 0.0, -9.0]".into()]).unwrap();
        assert!(matches!(read(&path, "dem_proc", &other), Err(CheckpointError::WrongScene { .. })));
    }

    #[test]
    fn coupled_processes_resume_from_the_newest_exchange_both_reached() {
        let dir = tempdir("common");
        let scene = scene();
        let x = |next| Some(ExchangeState { next, last_exchange: next - 1, last_time: 0.0, exchanges: next });
        let mut dem = CheckpointWriter::new(&dir, "dem_proc", &scene).unwrap();
        let mut lbm = CheckpointWriter::new(&dir, "lbm_proc", &scene).unwrap();
        dem.write(driver(570), x(10), |_| Ok(())).unwrap();
        lbm.write(driver(10), x(10), |_| Ok(())).unwrap();
        // The DEM got one further before the kill.
        dem.write(driver(1140), x(20), |_| Ok(())).unwrap();
        let (set, _) = latest_common(&folder(&dir), &["dem_proc", "lbm_proc"], &scene);
        let set = set.unwrap();
        assert_eq!((set[0].1.driver.steps, set[1].1.driver.steps), (570, 10));
    }

    fn tempdir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("sgf-ckpt-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }
}
