//! Hot reload: watches the scene file and the mesh files it names, and says when one changed.

use notify::{EventKind, RecursiveMode, Watcher};
use std::collections::HashSet;
use std::path::{Path, PathBuf};

/// A watch on a set of files. Editors save by writing in place or by writing a new file and
/// renaming it over the old one, so the folders holding the files are watched, and every
/// event naming one of the files counts.
pub struct FileWatch {
    _watcher: notify::RecommendedWatcher,
    files: Vec<PathBuf>,
}

impl FileWatch {
    /// Watches `files`; `changed` runs (on the watcher's thread) after each event that touches
    /// one of them.
    pub fn new(
        files: &[PathBuf],
        changed: impl Fn() + Send + 'static,
    ) -> Result<FileWatch, String> {
        let absolute: Vec<PathBuf> = files.iter().map(|f| absolute(f)).collect();
        let wanted: HashSet<PathBuf> = absolute.iter().cloned().collect();
        let mut watcher =
            notify::recommended_watcher(move |event: notify::Result<notify::Event>| {
                let Ok(event) = event else { return };
                if matches!(event.kind, EventKind::Access(_)) {
                    return;
                }
                if event.paths.iter().any(|p| wanted.contains(&absolute_of(p))) {
                    changed();
                }
            })
            .map_err(|e| format!("cannot watch files for changes: {e}"))?;
        let folders: HashSet<PathBuf> = absolute
            .iter()
            .filter_map(|f| f.parent().map(Path::to_path_buf))
            .collect();
        for folder in &folders {
            watcher
                .watch(folder, RecursiveMode::NonRecursive)
                .map_err(|e| format!("{}: cannot watch for changes: {e}", folder.display()))?;
        }
        Ok(FileWatch {
            _watcher: watcher,
            files: absolute,
        })
    }

    /// The files watched.
    pub fn files(&self) -> &[PathBuf] {
        &self.files
    }

    /// Whether the files watched are `files`, as a set.
    pub fn watches(&self, files: &[PathBuf]) -> bool {
        let want: HashSet<PathBuf> = files.iter().map(|f| absolute(f)).collect();
        want == self.files.iter().cloned().collect()
    }
}

/// `path` made absolute, its folder resolved through symbolic links (the file itself may be
/// missing for a moment while an editor replaces it).
fn absolute(path: &Path) -> PathBuf {
    let path = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    absolute_of(&path)
}

fn absolute_of(path: &Path) -> PathBuf {
    match (path.parent(), path.file_name()) {
        (Some(dir), Some(name)) => dir
            .canonicalize()
            .map(|d| d.join(name))
            .unwrap_or_else(|_| path.to_path_buf()),
        _ => path.to_path_buf(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::mpsc::channel;
    use std::time::Duration;

    #[test]
    fn an_edit_and_a_rename_over_the_file_are_seen_and_other_files_are_not() {
        let dir = tempfile::tempdir().unwrap();
        let scene = dir.path().join("scene.ron");
        std::fs::write(&scene, "a").unwrap();
        let (tx, rx) = channel();
        let _watch = FileWatch::new(std::slice::from_ref(&scene), move || {
            let _ = tx.send(());
        })
        .unwrap();
        std::fs::write(dir.path().join("other.txt"), "x").unwrap();
        assert!(rx.recv_timeout(Duration::from_millis(300)).is_err());
        std::fs::write(&scene, "b").unwrap();
        rx.recv_timeout(Duration::from_secs(5))
            .expect("an edit in place");
        while rx.try_recv().is_ok() {}
        let tmp = dir.path().join(".scene.ron.swp");
        std::fs::write(&tmp, "c").unwrap();
        std::fs::rename(&tmp, &scene).unwrap();
        rx.recv_timeout(Duration::from_secs(5))
            .expect("a rename over the file");
    }
}
