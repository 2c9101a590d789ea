//! Reading a recording: a file in any [`Format`] -> batches of [`RawFrame`]s.
//!
//! Synchronous on purpose: a replay is CPU-bound parsing of a local file, and the caller
//! decides where it runs (a blocking task in the daemon, a plain loop in tools and tests).

use super::{
    detect::{detect, DETECT_HEAD_BYTES},
    parser_for, FeedError, Format, FrameParser, ParseStats, RawFrame,
};
use std::fs::File;
use std::io::{ErrorKind, Read};
use std::path::{Path, PathBuf};

/// Bytes read from the file per batch: 1 MiB, about 45,000 Beast frames, so that at fleet
/// scale each aircraft task is woken for ~45 messages at a time. Every batch an aircraft
/// gets costs the same whatever its size (a channel hop, a wake-up, a published snapshot,
/// its aircraft's state brought back into cache): at 64 KiB (~3 messages a batch) that was
/// 10 % of the CPU; from 256 KiB (~11) to 1 MiB it was still 8 % of `kalman-cv`'s fleet
/// replay instructions and 5 % of its CPU (4.8 % and 7 % for `hybrid`). A paced replay
/// sends 50 ms slices whatever the chunk.
pub const CHUNK_BYTES: usize = 1024 * 1024;

/// A recording opened for reading, frame batch by frame batch.
pub struct FileReader {
    path: PathBuf,
    file: Box<dyn Read + Send>,
    format: Format,
    parser: Box<dyn FrameParser>,
    /// Bytes read but not consumed yet: an incomplete frame or line, and (right after
    /// opening with detection) the head that was sniffed.
    pending: Vec<u8>,
    bytes_read: u64,
    total_bytes: u64,
    done: bool,
}

impl FileReader {
    /// Opens `path`; `format` `None` detects it from the first [`DETECT_HEAD_BYTES`].
    /// `nominal_rate_hz` paces untimed AVR frames (see [`parser_for`]).
    pub fn open(
        path: impl AsRef<Path>,
        format: Option<Format>,
        nominal_rate_hz: f64,
    ) -> Result<Self, FeedError> {
        let path = path.as_ref().to_path_buf();
        let io_err = |source| FeedError::Io {
            path: path.clone(),
            error: source,
        };
        let file = File::open(&path).map_err(io_err)?;
        let total_bytes = file.metadata().map_err(io_err)?.len();
        Self::from_reader(Box::new(file), path, total_bytes, format, nominal_rate_hz)
    }

    /// A recording held in memory (the daemon's embedded default); `name` stands for the path
    /// in messages.
    pub fn from_bytes(
        bytes: &'static [u8],
        name: &str,
        format: Option<Format>,
        nominal_rate_hz: f64,
    ) -> Result<Self, FeedError> {
        Self::from_reader(
            Box::new(bytes),
            PathBuf::from(name),
            bytes.len() as u64,
            format,
            nominal_rate_hz,
        )
    }

    fn from_reader(
        mut file: Box<dyn Read + Send>,
        path: PathBuf,
        total_bytes: u64,
        format: Option<Format>,
        nominal_rate_hz: f64,
    ) -> Result<Self, FeedError> {
        let io_err = |source| FeedError::Io {
            path: path.clone(),
            error: source,
        };
        let mut pending = Vec::with_capacity(CHUNK_BYTES + DETECT_HEAD_BYTES);
        let format = match format {
            Some(format) => format,
            None => {
                pending.resize(DETECT_HEAD_BYTES, 0);
                let n = read_full(file.as_mut(), &mut pending).map_err(io_err)?;
                pending.truncate(n);
                detect(&pending).ok_or_else(|| FeedError::UnknownFormat { path: path.clone() })?
            }
        };
        Ok(Self {
            bytes_read: pending.len() as u64,
            parser: parser_for(format, nominal_rate_hz),
            path,
            file,
            format,
            pending,
            total_bytes,
            done: false,
        })
    }

    /// Clears `out` and fills it with the frames of the next chunk of the file.
    ///
    /// `Ok(true)`: `out` holds this batch (possibly empty, if the chunk was all garbage) and
    /// there may be more. `Ok(false)`: end of file and `out` is empty. The call that reaches
    /// the end parses a final line without newline, counts any incomplete tail
    /// ([`ParseStats::truncated_tail_bytes`]) and returns `Ok(true)` if that gave frames, so
    /// `while reader.next_batch(&mut out)? { use(&out) }` sees every frame.
    pub fn next_batch(&mut self, out: &mut Vec<RawFrame>) -> Result<bool, FeedError> {
        out.clear();
        if self.done {
            return Ok(false);
        }
        let filled = self.pending.len();
        self.pending.resize(filled + CHUNK_BYTES, 0);
        let n = match read_full(
            self.file.as_mut(),
            self.pending.get_mut(filled..).unwrap_or(&mut []),
        ) {
            Ok(n) => n,
            Err(source) => {
                self.pending.truncate(filled);
                return Err(FeedError::Io {
                    path: self.path.clone(),
                    error: source,
                });
            }
        };
        self.pending.truncate(filled + n);
        self.bytes_read += n as u64;
        let used = self
            .parser
            .parse(&self.pending, out)
            .min(self.pending.len());
        self.pending.drain(..used);
        if n == 0 {
            self.parser.finish_into(&self.pending, out);
            self.pending.clear();
            self.done = true;
            return Ok(!out.is_empty());
        }
        Ok(true)
    }

    /// Every remaining frame of the file, and the parser's counters at its end.
    pub fn read_all(mut self) -> Result<(Vec<RawFrame>, ParseStats), FeedError> {
        let mut all = Vec::new();
        let mut batch = Vec::new();
        while self.next_batch(&mut batch)? {
            all.extend_from_slice(&batch);
        }
        Ok((all, self.stats().clone()))
    }

    /// The format being read (given or detected).
    pub fn format(&self) -> Format {
        self.format
    }

    /// The parser's counters so far.
    pub fn stats(&self) -> &ParseStats {
        self.parser.stats()
    }

    /// Bytes read from the file so far (for a progress line).
    pub fn bytes_read(&self) -> u64 {
        self.bytes_read
    }

    /// The file's size when it was opened.
    pub fn total_bytes(&self) -> u64 {
        self.total_bytes
    }
}

/// Reads until `buf` is full or the file ends; returns the bytes read.
fn read_full(file: &mut dyn Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut filled = 0;
    while let Some(rest) = buf.get_mut(filled..) {
        if rest.is_empty() {
            break;
        }
        match file.read(rest) {
            Ok(0) => break,
            Ok(n) => filled += n,
            Err(e) if e.kind() == ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(filled)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn missing_file_and_unknown_format_are_errors() {
        let err = FileReader::open("/nonexistent/feed.avr", None, 1.0).err();
        assert!(matches!(err, Some(FeedError::Io { .. })), "{err:?}");
        let text = err.map(|e| e.to_string()).unwrap_or_default();
        assert!(
            text.starts_with("cannot read /nonexistent/feed.avr: "),
            "{text}"
        );

        let path = std::env::temp_dir().join(format!("feed-unknown-{}.txt", std::process::id()));
        std::fs::write(&path, "hello\nworld\n").unwrap();
        let err = FileReader::open(&path, None, 1.0).err();
        std::fs::remove_file(&path).unwrap();
        assert!(
            matches!(err, Some(FeedError::UnknownFormat { .. })),
            "{err:?}"
        );
    }

    #[test]
    fn reads_a_small_file_to_the_end() {
        let path = std::env::temp_dir().join(format!("feed-small-{}.csv", std::process::id()));
        std::fs::write(
            &path,
            "1.0,5DAD57202809F9\n2.0,5DAD57202809F9\n3.0,5DAD5720",
        )
        .unwrap();
        let mut r = FileReader::open(&path, None, 1.0).unwrap();
        std::fs::remove_file(&path).unwrap();
        assert_eq!(r.format(), Format::Csv);
        assert_eq!(r.total_bytes(), 50);
        let mut out = Vec::new();
        let mut times = Vec::new();
        while r.next_batch(&mut out).unwrap() {
            times.extend(out.iter().map(|f| f.time_s));
        }
        assert_eq!(times, [1.0, 2.0]);
        assert_eq!(r.bytes_read(), 50);
        assert_eq!(r.stats().truncated_tail_bytes, 12);
        assert!(!r.next_batch(&mut out).unwrap());
    }
}
