//! File-system access of the library: reading netlists and writing outputs
//! atomically; the process's memory setup. Stages never touch the file
//! system themselves.

use std::io::Write;
use std::path::Path;

use crate::front::Loader;

/// Opt this process out of transparent huge pages (Linux).
///
/// With THP on `always`, the first touch of any page of the allocator's
/// arenas makes the kernel clear a whole 2 MiB page. A big circuit's IR is
/// many small objects spread over fresh memory, so the kernel time dominated
/// cold runs: `kausal sort` of a 10^5-section ladder took 1.3–1.55 s (0.7–1.0 s
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

/// Reads include files from disk.
#[derive(Clone, Copy, Debug, Default)]
pub struct FsLoader;

impl Loader for FsLoader {
    fn load(&self, path: &Path) -> std::io::Result<String> {
        std::fs::read_to_string(path)
    }
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
/// [`remove_pending_on_interrupt`].
pub struct AtomicFile {
    /// `None` only while [`AtomicFile::commit`] consumes it.
    tmp: Option<std::io::BufWriter<tempfile::NamedTempFile>>,
    tmp_path: std::path::PathBuf,
    path: std::path::PathBuf,
}

/// The temporary files of the [`AtomicFile`]s not yet committed or dropped.
static PENDING: std::sync::Mutex<Vec<std::path::PathBuf>> = std::sync::Mutex::new(Vec::new());

fn pending() -> std::sync::MutexGuard<'static, Vec<std::path::PathBuf>> {
    PENDING.lock().unwrap_or_else(|e| e.into_inner())
}

/// On an interrupt, remove the temporary files of the outputs being written
/// and exit with 130 (128 + SIGINT): a long run stopped by the user leaves
/// neither a half-written output nor a stray temporary beside it.
pub fn remove_pending_on_interrupt() {
    let _ = ctrlc::set_handler(|| {
        for p in pending().drain(..) {
            let _ = std::fs::remove_file(p);
        }
        std::process::exit(130);
    });
}

impl AtomicFile {
    pub fn create(path: &Path) -> std::io::Result<AtomicFile> {
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
        let tmp = builder.tempfile_in(dir)?;
        let tmp_path = tmp.path().to_path_buf();
        pending().push(tmp_path.clone());
        Ok(AtomicFile {
            tmp: Some(std::io::BufWriter::with_capacity(1 << 16, tmp)),
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
        let tmp = tmp.into_inner().map_err(|e| e.into_error())?;
        tmp.persist(&self.path).map_err(|e| e.error)?;
        Ok(())
    }

    fn writer(&mut self) -> &mut std::io::BufWriter<tempfile::NamedTempFile> {
        self.tmp
            .as_mut()
            .expect("an AtomicFile is written only before its commit")
    }
}

impl Drop for AtomicFile {
    /// Committed or not, its temporary is no longer the interrupt's business
    /// (renamed, or removed by the `NamedTempFile` dropped with it).
    fn drop(&mut self) {
        pending().retain(|p| *p != self.tmp_path);
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
