//! Every relative link in the repository's Markdown resolves inside the repository, so a
//! clone with nothing beside it has all of its documents (checked by `cargo test -p xtask`).

use std::path::{Path, PathBuf};

/// The Markdown files of the repository (not build output, not the fuzz corpus).
fn markdown_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let p = e.path();
        let name = e.file_name();
        let name = name.to_string_lossy();
        if p.is_dir() {
            if !(name.starts_with('.')
                || name == "target"
                || name == "corpus"
                || name == "artifacts")
            {
                markdown_files(&p, out);
            }
        } else if name.ends_with(".md") {
            out.push(p);
        }
    }
}

/// The targets of the inline links `[text](target)` and images `![alt](target)` in `text`
/// that are neither web addresses nor anchors within the page (the anchor part removed).
pub fn relative_links(text: &str) -> Vec<String> {
    let mut links = Vec::new();
    let mut rest = text;
    while let Some(i) = rest.find("](") {
        rest = &rest[i + 2..];
        let Some(end) = rest.find(')') else { break };
        let target = rest[..end].split_whitespace().next().unwrap_or("");
        let path = target.split('#').next().unwrap_or("");
        if !(path.is_empty() || target.contains("://") || target.starts_with("mailto:")) {
            links.push(path.to_string());
        }
    }
    links
}

/// The links that do not resolve, as "file: target".
pub fn broken(root: &Path) -> Vec<String> {
    let mut files = Vec::new();
    markdown_files(root, &mut files);
    let mut bad = Vec::new();
    for f in files {
        let Ok(text) = std::fs::read_to_string(&f) else {
            continue;
        };
        let dir = f.parent().unwrap_or(root);
        for l in relative_links(&text) {
            let target = dir.join(&l);
            let inside = target
                .canonicalize()
                .is_ok_and(|t| t.starts_with(root.canonicalize().unwrap_or_default()));
            if !inside {
                bad.push(format!(
                    "{}: {l}",
                    f.strip_prefix(root).unwrap_or(&f).display()
                ));
            }
        }
    }
    bad
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_relative_links_only() {
        let t = "see [a](docs/A.md#x), ![f](fig.svg \"t\"), [w](https://e.org/x), [s](#top)";
        assert_eq!(relative_links(t), vec!["docs/A.md", "fig.svg"]);
    }

    #[test]
    fn a_missing_or_outside_target_is_broken() {
        let dir = std::env::temp_dir().join(format!("links-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("docs")).unwrap();
        std::fs::write(dir.join("docs/B.md"), "b").unwrap();
        std::fs::write(
            dir.join("README.md"),
            "[ok](docs/B.md) [gone](docs/C.md) [out](../elsewhere/X.md)",
        )
        .unwrap();
        let bad = broken(&dir);
        std::fs::remove_dir_all(&dir).unwrap();
        assert_eq!(
            bad,
            vec!["README.md: docs/C.md", "README.md: ../elsewhere/X.md"]
        );
    }

    #[test]
    fn every_link_in_the_repository_resolves_inside_it() {
        let bad = broken(&crate::util::root());
        assert!(
            bad.is_empty(),
            "links that do not resolve:\n{}",
            bad.join("\n")
        );
    }
}
