//! Loading a netlist's files: the [`Loader`] that reads them (the file
//! system's own rules live in `crate::io`), decoding their bytes into text,
//! and following `.include` and `.lib` lines into a [`SourceMap`].

use std::path::{Path, PathBuf};

use super::error::ParseError;
use super::{lex, parse};
use crate::diag::{FileId, SourceMap, Span};

/// Reads files for the front end; the CLI passes [`crate::io::FsLoader`].
pub trait Loader {
    /// The file's bytes, which must not be read without bound: a loader
    /// refuses what is not a regular file, or is too large.
    fn load(&self, path: &Path) -> Result<Vec<u8>, LoadError>;
}

/// Why a [`Loader`] gave no bytes.
#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    /// The file system refused (no such file, no permission, …).
    #[error("{0}")]
    Io(#[from] std::io::Error),
    /// The path names something else than a regular file.
    #[error("it is {kind}, not a file")]
    NotAFile { kind: FileKind },
    /// The file has more than `limit` bytes.
    #[error("it is larger than {}", mib(*limit))]
    TooLarge { limit: u64 },
}

/// What a path names when it is not a regular file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FileKind {
    Directory,
    /// A named pipe: reading it waits for a writer, possibly for ever.
    Fifo,
    /// A character device such as `/dev/zero`, which never ends.
    CharDevice,
    BlockDevice,
    Socket,
    Other,
}

impl std::fmt::Display for FileKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            FileKind::Directory => "a directory",
            FileKind::Fifo => "a FIFO (named pipe)",
            FileKind::CharDevice => "a character device",
            FileKind::BlockDevice => "a block device",
            FileKind::Socket => "a socket",
            FileKind::Other => "not a regular file",
        })
    }
}

/// `64 MiB`, or the bytes when not a whole number of MiB.
pub fn mib(bytes: u64) -> String {
    if bytes.is_multiple_of(1 << 20) {
        format!("{} MiB", bytes >> 20)
    } else {
        format!("{bytes} bytes")
    }
}

/// Where `.include PATH` written in `from` points.
pub fn resolve_include(from: &Path, path: &str) -> PathBuf {
    let p = Path::new(path);
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        from.parent().unwrap_or(Path::new("")).join(p)
    }
}

/// A file's bytes as text: every maximal invalid UTF-8 sequence becomes one
/// U+FFFD, whose offset in the text and first byte are kept (in order).
struct Decoded {
    text: String,
    invalid: Vec<(usize, u8)>,
}

fn decode(bytes: Vec<u8>) -> Decoded {
    let bytes = match String::from_utf8(bytes) {
        Ok(text) => {
            return Decoded {
                text,
                invalid: Vec::new(),
            };
        }
        Err(e) => e.into_bytes(),
    };
    let mut text = String::with_capacity(bytes.len() + 2);
    let mut invalid = Vec::new();
    for chunk in bytes.utf8_chunks() {
        text.push_str(chunk.valid());
        if let Some(&first) = chunk.invalid().first() {
            invalid.push((text.len(), first));
            text.push(char::REPLACEMENT_CHARACTER);
        }
    }
    Decoded { text, invalid }
}

/// Add `root` (already read) to a new [`SourceMap`], then every file it
/// includes, recursively. Problems (missing files, cycles) are returned beside
/// the map; parsing can still proceed without the missing files.
pub fn load(
    name: &str,
    path: &Path,
    text: String,
    loader: &dyn Loader,
) -> (SourceMap, Vec<ParseError>) {
    load_bytes(name, path, text.into_bytes(), loader)
}

/// [`load`] of a root file's bytes, which need not be UTF-8 (see
/// [`add_decoded`]).
pub fn load_bytes(
    name: &str,
    path: &Path,
    bytes: Vec<u8>,
    loader: &dyn Loader,
) -> (SourceMap, Vec<ParseError>) {
    let mut sources = SourceMap::default();
    let mut errors = Vec::new();
    let root = add_decoded(&mut sources, name, path, bytes, true, &mut errors);
    let mut stack = vec![root];
    load_includes(&mut sources, root, true, loader, &mut stack, &mut errors);
    (sources, errors)
}

/// Add a file's bytes to `sources` as text. Bytes that are not UTF-8 are
/// shown as U+FFFD; ngspice reads bytes, so in comments and the title they
/// are accepted as it accepts them (Latin-1 remarks in old netlists), but
/// the first one inside a statement is an error pointing at it.
fn add_decoded(
    sources: &mut SourceMap,
    name: &str,
    path: &Path,
    bytes: Vec<u8>,
    is_root: bool,
    errors: &mut Vec<ParseError>,
) -> FileId {
    let Decoded { text, invalid } = decode(bytes);
    let id = sources.add(name, path, text);
    if invalid.is_empty() {
        return id;
    }
    let mut scratch = Vec::new();
    let lexed = lex::lex_file(sources, id, is_root, &mut scratch);
    let tokens: Vec<Span> = lexed
        .lines()
        .iter()
        .flat_map(|l| l.tokens.iter().map(|t| t.span))
        .collect();
    // Tokens come in file order and do not overlap.
    let in_token = |at: usize| {
        let k = tokens.partition_point(|t| (t.end as usize) <= at);
        tokens.get(k).is_some_and(|t| (t.start as usize) <= at)
    };
    if let Some(&(at, byte)) = invalid.iter().find(|&&(at, _)| in_token(at)) {
        let end = at + char::REPLACEMENT_CHARACTER.len_utf8();
        errors.push(ParseError::NotUtf8 {
            span: Span::new(id, at, end),
            byte,
        });
    }
    id
}

fn load_includes(
    sources: &mut SourceMap,
    file: FileId,
    is_root: bool,
    loader: &dyn Loader,
    stack: &mut Vec<FileId>,
    errors: &mut Vec<ParseError>,
) {
    // Lex to find the include lines (the parse lexes again), but only when
    // some line could be one.
    let may_include = sources.file(file).text.lines().any(|l| {
        let l = l.trim_start().as_bytes();
        l.len() >= 4
            && (l[..4].eq_ignore_ascii_case(b".inc") || l[..4].eq_ignore_ascii_case(b".lib"))
    });
    if !may_include {
        return;
    }
    // `.include PATH` and `.lib PATH SECTION` (`.lib NAME` opens a section).
    let includes: Vec<(String, Span, bool)> = {
        let mut scratch = Vec::new();
        let lexed = lex::lex_file(sources, file, is_root, &mut scratch);
        lexed
            .lines()
            .iter()
            .filter_map(|l| {
                let lib = l.tokens[0].is_word(".lib") && l.tokens.len() >= 3;
                let include = l.tokens[0].is_word(".include") || l.tokens[0].is_word(".inc");
                (lib || include)
                    .then_some(l.tokens.get(1)?)
                    .map(|t| (t.text.trim_matches('"').to_string(), t.span, lib))
            })
            .collect()
    };
    let from = sources.file(file).path.clone();
    for (path, span, lib) in includes {
        let resolved = resolve_include(&from, &path);
        if let Some(existing) = sources.find_path(&resolved) {
            // A library's sections may use each other (the parser checks
            // that no section uses itself).
            if stack.contains(&existing) && !lib {
                errors.push(ParseError::IncludeCycle { span, path });
            }
            continue;
        }
        // Reading includes recurses: a chain deeper than the parser reads is
        // not loaded (the parser says so where it stops).
        if stack.len() > parse::MAX_NESTING {
            continue;
        }
        match loader.load(&resolved) {
            Ok(bytes) => {
                let name = resolved.display().to_string();
                let id = add_decoded(sources, &name, &resolved, bytes, false, errors);
                stack.push(id);
                load_includes(sources, id, false, loader, stack, errors);
                stack.pop();
            }
            Err(e) => errors.push(ParseError::include_failed(span, path, e)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decoding_keeps_where_each_invalid_sequence_was() {
        let d = decode(b"ab\xffc\xe2\x82d\xf0".to_vec());
        assert_eq!(d.text, "ab\u{fffd}c\u{fffd}d\u{fffd}");
        assert_eq!(d.invalid, vec![(2, 0xff), (6, 0xe2), (10, 0xf0)]);
        let d = decode("µ ok".as_bytes().to_vec());
        assert!(d.invalid.is_empty());
    }
}
