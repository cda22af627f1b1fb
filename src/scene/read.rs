//! Reading the files a scene names (scene files, meshes, buffers, material libraries,
//! textures): whole regular files only.
//!
//! `std::fs::read` reads until end of file, which a device or a pipe (a mesh path that links
//! to `/dev/zero`, say) never reaches: it would take memory until the system refuses. A
//! regular file's size is known before it is read, so only those are read.

use std::io;
use std::path::Path;

/// The bytes of the regular file at `path` (symbolic links followed).
pub fn read(path: &Path) -> io::Result<Vec<u8>> {
    let meta = std::fs::metadata(path)?;
    if meta.is_dir() {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            "is a directory",
        ));
    }
    if !meta.is_file() {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            "not a regular file (a device or a pipe is not read)",
        ));
    }
    std::fs::read(path)
}

/// The text of the regular file at `path`, which must be UTF-8.
pub fn read_to_string(path: &Path) -> io::Result<String> {
    String::from_utf8(read(path)?).map_err(|_| {
        io::Error::new(
            io::ErrorKind::InvalidData,
            "stream did not contain valid UTF-8",
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn regular_files_are_read_and_devices_refused() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("a.obj");
        std::fs::write(&file, b"v 0 0 0\n").unwrap();
        assert_eq!(read(&file).unwrap(), b"v 0 0 0\n");
        assert_eq!(read_to_string(&file).unwrap(), "v 0 0 0\n");
        assert!(
            read(dir.path())
                .unwrap_err()
                .to_string()
                .contains("directory")
        );
        #[cfg(unix)]
        {
            // A link to an endless device: refused before a byte is read.
            let link = dir.path().join("zero.obj");
            std::os::unix::fs::symlink("/dev/zero", &link).unwrap();
            let e = read(&link).unwrap_err();
            assert_eq!(e.kind(), io::ErrorKind::InvalidInput, "{e}");
        }
        std::fs::write(&file, [0xff, 0xfe, 0]).unwrap();
        assert_eq!(
            read_to_string(&file).unwrap_err().kind(),
            io::ErrorKind::InvalidData
        );
    }
}
