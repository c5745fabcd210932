//! File-system access of the library: reading netlists (regular files of
//! bounded size only) and writing outputs atomically; the process's memory
//! setup. Stages never touch the file
//! system themselves.

use std::io::Write;
use std::path::Path;

use crate::front::{FileKind, LoadError, Loader};

/// Opt this process out of transparent huge pages (Linux).
///
/// With THP on `always`, the first touch of any page of the allocator's
/// arenas makes the kernel clear a whole 2 MiB page. A big circuit's IR is
/// many small objects spread over fresh memory, so the kernel time dominates
/// cold runs: `kausal sort` of a 10^5-section ladder takes 1.3–1.55 s (0.7–1.0 s
/// system time) with THP and 0.85 s (0.2 s) without; its simulation 4.8–4.9 s
/// against 4.2 s, the solve itself unchanged. `KAUSAL_THP=1` keeps THP.
pub fn no_huge_pages() {
    if std::env::var_os("KAUSAL_THP").is_some() {
        return;
    }
    #[cfg(target_os = "linux")]
    // SAFETY: PR_SET_THP_DISABLE takes integer arguments and only sets a flag
    // of the calling process; no memory is touched.
    unsafe {
        libc::prctl(libc::PR_SET_THP_DISABLE, 1, 0, 0, 0);
    }
}

/// The largest netlist or include file read, in bytes: far above any real
/// netlist, far below what would exhaust memory.
pub const MAX_NETLIST_BYTES: u64 = 64 << 20;

/// Reads netlist and include files from disk with [`read_netlist`].
#[derive(Clone, Copy, Debug, Default)]
pub struct FsLoader;

impl Loader for FsLoader {
    fn load(&self, path: &Path) -> Result<Vec<u8>, LoadError> {
        read_netlist(path)
    }
}

/// The bytes of the regular file at `path`, at most [`MAX_NETLIST_BYTES`]
/// of them. Anything else is refused before it is read: a FIFO would block
/// for ever, `/dev/zero` never ends, a directory has no text.
pub fn read_netlist(path: &Path) -> Result<Vec<u8>, LoadError> {
    use std::io::Read;
    let limit = MAX_NETLIST_BYTES;
    // Checked before opening, as opening a FIFO waits for a writer (and a
    // device may act on being opened) ...
    let meta = std::fs::metadata(path)?;
    if !meta.is_file() {
        return Err(LoadError::NotAFile {
            kind: kind_of(meta.file_type()),
        });
    }
    let mut options = std::fs::OpenOptions::new();
    options.read(true);
    // ... and again on what was opened, which may have been replaced since:
    // without blocking, so that a FIFO put there cannot hang the open.
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.custom_flags(libc::O_NONBLOCK);
    }
    let file = options.open(path)?;
    let meta = file.metadata()?;
    if !meta.is_file() {
        return Err(LoadError::NotAFile {
            kind: kind_of(meta.file_type()),
        });
    }
    if meta.len() > limit {
        return Err(LoadError::TooLarge { limit });
    }
    // A file growing while it is read stops at the bound too.
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    file.take(limit + 1).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > limit {
        return Err(LoadError::TooLarge { limit });
    }
    Ok(bytes)
}

fn kind_of(t: std::fs::FileType) -> FileKind {
    if t.is_dir() {
        return FileKind::Directory;
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_fifo() {
            return FileKind::Fifo;
        }
        if t.is_char_device() {
            return FileKind::CharDevice;
        }
        if t.is_block_device() {
            return FileKind::BlockDevice;
        }
        if t.is_socket() {
            return FileKind::Socket;
        }
    }
    FileKind::Other
}

/// Write `bytes` to `path` through a temporary file in the same directory and
/// a rename, so that a reader never sees a half-written file.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let mut f = AtomicFile::create(path)?;
    f.write_all(bytes)?;
    f.commit()
}

/// A file written in pieces through a temporary file in the same directory,
/// renamed over its path by [`AtomicFile::commit`]; dropped uncommitted (an
/// error on the way), it leaves nothing behind and the old file untouched.
/// Interrupted (Ctrl-C, SIGTERM, SIGHUP), the process removes it too: see
/// [`remove_pending_on_interrupt`]. A path that names something other than
/// a regular file (`/dev/null`, `/dev/stdout`, a FIFO) is written directly:
/// a rename would replace the device or pipe with a regular file. A
/// symbolic link to a regular file is kept: the file it points to is
/// replaced.
pub struct AtomicFile {
    /// `None` only while [`AtomicFile::commit`] consumes it.
    tmp: Option<std::io::BufWriter<Sink>>,
    tmp_path: std::path::PathBuf,
    path: std::path::PathBuf,
}

/// Where an [`AtomicFile`] writes.
enum Sink {
    Temporary(tempfile::NamedTempFile),
    Direct(std::fs::File),
}

impl Write for Sink {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        match self {
            Sink::Temporary(f) => f.write(buf),
            Sink::Direct(f) => f.write(buf),
        }
    }
    fn flush(&mut self) -> std::io::Result<()> {
        match self {
            Sink::Temporary(f) => f.flush(),
            Sink::Direct(f) => f.flush(),
        }
    }
}

/// The temporary files of the [`AtomicFile`]s not yet committed or dropped.
static PENDING: std::sync::Mutex<Vec<std::path::PathBuf>> = std::sync::Mutex::new(Vec::new());

/// A registry of what the interrupt handler cleans up, locked (a panic
/// elsewhere while it was held leaves it usable).
fn registry<T>(r: &'static std::sync::Mutex<Vec<T>>) -> std::sync::MutexGuard<'static, Vec<T>> {
    r.lock().unwrap_or_else(|e| e.into_inner())
}

/// `make` something and register its `key`, under the registry's lock so that
/// an interrupt in between cannot miss it; after an interrupt, nothing.
fn register<T, R>(
    r: &'static std::sync::Mutex<Vec<T>>,
    make: impl FnOnce() -> std::io::Result<R>,
    key: impl FnOnce(&R) -> T,
) -> std::io::Result<R> {
    let mut live = registry(r);
    if INTERRUPTED.load(std::sync::atomic::Ordering::SeqCst) {
        return Err(std::io::Error::new(
            std::io::ErrorKind::Interrupted,
            "interrupted",
        ));
    }
    let made = make()?;
    live.push(key(&made));
    Ok(made)
}

/// Set first thing by the interrupt handler.
static INTERRUPTED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// The live [`ScratchDir`]s.
static SCRATCH: std::sync::Mutex<Vec<std::path::PathBuf>> = std::sync::Mutex::new(Vec::new());

/// The children started by [`run_child`] and not yet reaped.
static CHILDREN: std::sync::Mutex<Vec<u32>> = std::sync::Mutex::new(Vec::new());

/// On an interrupt, kill the children it runs (ngspice, `kausal sim` under
/// `kausal bench`), remove its scratch directories and the temporary files
/// of the outputs being written, and exit with 130 (128 + SIGINT): a long
/// run stopped by the user leaves neither a half-written output, nor a stray
/// temporary beside it, nor an ngspice scratch directory in `$TMPDIR`.
pub fn remove_pending_on_interrupt() {
    let _ = ctrlc::set_handler(|| {
        // The main thread runs on until the exit: it starts nothing new.
        INTERRUPTED.store(true, std::sync::atomic::Ordering::SeqCst);
        for pid in registry(&CHILDREN).drain(..) {
            if let Ok(pid) = libc::pid_t::try_from(pid) {
                // Killed outright and waited for: a child given time to
                // exit could still be writing into its scratch directory
                // while that is removed, which would then stay.
                // SAFETY: kill(2) and waitpid(2) on a child this process
                // started; waitpid only fails (ECHILD) if it was reaped.
                unsafe {
                    libc::kill(pid, libc::SIGKILL);
                    libc::waitpid(pid, std::ptr::null_mut(), 0);
                }
            }
        }
        // The main thread runs on meanwhile and may be writing into a
        // directory (ngspice's netlist): removal fails while it does (not
        // empty) and is retried, for at most a second.
        for d in registry(&SCRATCH).drain(..) {
            for _ in 0..200 {
                match std::fs::remove_dir_all(&d) {
                    Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                        std::thread::sleep(std::time::Duration::from_millis(5));
                    }
                    _ => break,
                }
            }
        }
        for p in registry(&PENDING).drain(..) {
            let _ = std::fs::remove_file(p);
        }
        std::process::exit(130);
    });
}

/// A temporary directory (in `$TMPDIR`) removed when dropped, and by
/// [`remove_pending_on_interrupt`] if the process is interrupted first.
pub struct ScratchDir {
    dir: tempfile::TempDir,
}

impl ScratchDir {
    pub fn new() -> std::io::Result<ScratchDir> {
        let dir = register(&SCRATCH, tempfile::tempdir, |d| d.path().to_path_buf())?;
        Ok(ScratchDir { dir })
    }

    pub fn path(&self) -> &Path {
        self.dir.path()
    }
}

impl Drop for ScratchDir {
    /// Unregistered; the `TempDir` then removes it.
    fn drop(&mut self) {
        registry(&SCRATCH).retain(|p| p != self.dir.path());
    }
}

/// Run `cmd` to completion as [`std::process::Command::output`] does, with
/// the child known to [`remove_pending_on_interrupt`] while it runs. A child
/// still running after `limit` is killed and the error is `TimedOut`
/// (ngspice can loop without end at a tight reltol on a circuit it finds
/// hard: a `validate` then waited forever).
pub fn run_child(
    cmd: &mut std::process::Command,
    limit: std::time::Duration,
) -> std::io::Result<std::process::Output> {
    run_child_measured(cmd, limit).map(|(out, _)| out)
}

/// [`run_child`], with the child's peak resident memory in bytes where the
/// system reports it (`/proc/PID/status`, sampled every 2 ms: a peak in the
/// last 2 ms of a run can be missed).
pub fn run_child_measured(
    cmd: &mut std::process::Command,
    limit: std::time::Duration,
) -> std::io::Result<(std::process::Output, Option<u64>)> {
    use std::io::Read;
    let spawn = || {
        cmd.stdin(std::process::Stdio::null())
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
    };
    let mut child = register(&CHILDREN, spawn, std::process::Child::id)?;
    let pid = child.id();
    // Both pipes are drained while the child runs (a full pipe would stop it).
    fn drain<R: Read + Send + 'static>(pipe: Option<R>) -> std::thread::JoinHandle<Vec<u8>> {
        std::thread::spawn(move || {
            let mut buf = Vec::new();
            if let Some(mut p) = pipe {
                let _ = p.read_to_end(&mut buf);
            }
            buf
        })
    }
    let out = drain(child.stdout.take());
    let err = drain(child.stderr.take());
    let started = std::time::Instant::now();
    let mut peak = None;
    let status = loop {
        // The child's own high-water mark, sampled while it runs: wait4's
        // ru_maxrss would count the parent's pages the child shared before
        // it exec'd (a large bench process made every child look as large).
        if let Some(hwm) = high_water_mark(pid) {
            peak = Some(peak.map_or(hwm, |p: u64| p.max(hwm)));
        }
        if let Some(status) = child.try_wait()? {
            break Ok(status);
        }
        if started.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            break Err(std::io::Error::new(
                std::io::ErrorKind::TimedOut,
                format!("did not finish within {} s", limit.as_secs()),
            ));
        }
        std::thread::sleep(std::time::Duration::from_millis(2));
    };
    // Unregistered as soon as it is reaped: only in those few instructions
    // could an interrupt signal the pid after the kernel freed it.
    registry(&CHILDREN).retain(|&p| p != pid);
    let (stdout, stderr) = (
        out.join().unwrap_or_default(),
        err.join().unwrap_or_default(),
    );
    Ok((
        std::process::Output {
            status: status?,
            stdout,
            stderr,
        },
        peak,
    ))
}

/// The peak resident memory (`VmHWM`) of a running process, in bytes.
fn high_water_mark(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

impl AtomicFile {
    pub fn create(path: &Path) -> std::io::Result<AtomicFile> {
        match std::fs::metadata(path) {
            Ok(m) if !m.is_file() && !m.is_dir() => {
                let f = std::fs::OpenOptions::new().write(true).open(path)?;
                return Ok(AtomicFile {
                    tmp: Some(std::io::BufWriter::with_capacity(1 << 16, Sink::Direct(f))),
                    tmp_path: std::path::PathBuf::new(),
                    path: path.to_path_buf(),
                });
            }
            _ => {}
        }
        let linked;
        let path = match std::fs::symlink_metadata(path) {
            Ok(m) if m.file_type().is_symlink() => match std::fs::canonicalize(path) {
                Ok(p) => {
                    linked = p;
                    &linked
                }
                Err(_) => path,
            },
            _ => path,
        };
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        // Created as `File::create` would (0666 less the umask), not with the
        // temporary file's private 0600, which the rename would keep.
        let mut builder = tempfile::Builder::new();
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            builder.permissions(std::fs::Permissions::from_mode(0o666));
        }
        let tmp = register(
            &PENDING,
            || builder.tempfile_in(dir),
            |t| t.path().to_path_buf(),
        )?;
        let tmp_path = tmp.path().to_path_buf();
        Ok(AtomicFile {
            tmp: Some(std::io::BufWriter::with_capacity(
                1 << 16,
                Sink::Temporary(tmp),
            )),
            tmp_path,
            path: path.to_path_buf(),
        })
    }

    /// The path it will be renamed over.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Flush and rename over the path.
    pub fn commit(mut self) -> std::io::Result<()> {
        let tmp = self.tmp.take().expect("committed once (commit takes self)");
        match tmp.into_inner().map_err(|e| e.into_error())? {
            Sink::Temporary(tmp) => {
                tmp.persist(&self.path).map_err(|e| e.error)?;
            }
            Sink::Direct(_) => {}
        }
        Ok(())
    }

    /// Whether it writes straight into a pipe or a device (which cannot
    /// be rewound), not into a temporary file.
    pub fn is_direct(&self) -> bool {
        matches!(
            self.tmp.as_ref().map(|w| w.get_ref()),
            Some(Sink::Direct(_))
        )
    }

    /// Overwrite what was written at `offset` with `bytes` (a count in a
    /// header, known only at the end), then go on at the end.
    pub fn overwrite_at(&mut self, offset: u64, bytes: &[u8]) -> std::io::Result<()> {
        use std::io::{Seek, SeekFrom};
        let w = self.writer();
        w.flush()?;
        let f: &mut std::fs::File = match w.get_mut() {
            Sink::Temporary(t) => t.as_file_mut(),
            Sink::Direct(f) => f,
        };
        f.seek(SeekFrom::Start(offset))?;
        f.write_all(bytes)?;
        f.seek(SeekFrom::End(0))?;
        Ok(())
    }

    fn writer(&mut self) -> &mut std::io::BufWriter<Sink> {
        self.tmp
            .as_mut()
            .expect("an AtomicFile is written only before its commit")
    }
}

impl Drop for AtomicFile {
    /// Committed or not, its temporary is no longer the interrupt's business
    /// (renamed, or removed by the `NamedTempFile` dropped with it).
    fn drop(&mut self) {
        registry(&PENDING).retain(|p| *p != self.tmp_path);
    }
}

impl Write for AtomicFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.writer().write(buf)
    }
    fn write_all(&mut self, buf: &[u8]) -> std::io::Result<()> {
        self.writer().write_all(buf)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.writer().flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A symbolic link stays a link to the rewritten file, and a FIFO stays
    /// a FIFO, its reader getting the bytes (a rename over `/dev/null`
    /// replaced the device with a regular file).
    #[cfg(unix)]
    #[test]
    fn links_and_pipes_are_written_through() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("target.csv");
        let link = dir.path().join("link.csv");
        std::fs::write(&target, b"old").unwrap();
        std::os::unix::fs::symlink(&target, &link).unwrap();
        write_atomic(&link, b"new").unwrap();
        assert!(
            std::fs::symlink_metadata(&link)
                .unwrap()
                .file_type()
                .is_symlink()
        );
        assert_eq!(std::fs::read(&target).unwrap(), b"new");
        let fifo = dir.path().join("pipe");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        if !made.is_ok_and(|s| s.success()) {
            return;
        }
        let reader = {
            let fifo = fifo.clone();
            std::thread::spawn(move || std::fs::read(fifo).unwrap())
        };
        write_atomic(&fifo, b"through").unwrap();
        // Checked before the join: a FIFO renamed away leaves its reader
        // waiting.
        use std::os::unix::fs::FileTypeExt;
        assert!(std::fs::metadata(&fifo).unwrap().file_type().is_fifo());
        assert_eq!(reader.join().unwrap(), b"through");
    }

    /// The written file replaces the old one whole and gets the permissions
    /// `File::create` would give it.
    #[test]
    fn atomic_write_replaces_with_ordinary_permissions() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.csv");
        write_atomic(&path, b"first").unwrap();
        write_atomic(&path, b"second").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"second");
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let reference = dir.path().join("reference");
            std::fs::File::create(&reference).unwrap();
            let mode = |p: &Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
            assert_eq!(mode(&path), mode(&reference));
        }
    }
}
