//! The layers import only downwards: reads every library source file and
//! fails on a `crate::` path into a higher layer, or on `clap` outside the
//! binary. docs/architecture.md draws the same picture.

use std::path::{Path, PathBuf};

/// Top-level modules by layer: a module may use its own layer and lower ones.
const LAYERS: [(&str, u32); 22] = [
    ("error", 0),
    ("input", 0),
    ("timing", 0),
    ("progress", 0),
    ("json", 0),
    ("geometry", 0),
    ("remainder", 0),
    ("camera", 0),
    ("map", 1),
    ("spec", 2),
    ("plan", 3),
    ("world", 4),
    ("render", 5),
    ("output", 6),
    ("dataset", 7),
    ("validate", 7),
    ("analysis", 7),
    ("export", 7),
    ("preview", 7),
    ("map_view", 7),
    ("orchestrate", 8),
    ("cli", 9),
];

fn layer(module: &str) -> Option<u32> {
    LAYERS.iter().find(|(m, _)| *m == module).map(|(_, l)| *l)
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

#[test]
fn layers_import_only_downwards_and_clap_stays_in_the_binary() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let mut checked = 0;
    let mut violations = Vec::new();
    for file in &files {
        let rel = file.strip_prefix(&src).unwrap();
        let top = rel.components().next().unwrap().as_os_str().to_string_lossy();
        let module = top.trim_end_matches(".rs");
        if matches!(module, "main" | "cli" | "lib") {
            continue; // the binary, and the list of modules
        }
        let own = layer(module).unwrap_or_else(|| panic!("{module} (src/{}) has no layer in this test", rel.display()));
        let text = std::fs::read_to_string(file).unwrap();
        for (n, line) in text.lines().enumerate() {
            if line.contains("clap::") || line.contains("use clap") {
                violations.push(format!("src/{}:{}: clap outside the binary: {line}", rel.display(), n + 1));
            }
            for (i, _) in line.match_indices("crate::") {
                let used: String =
                    line[i + 7..].chars().take_while(|c| c.is_ascii_alphanumeric() || *c == '_').collect();
                let Some(theirs) = layer(&used) else { continue };
                checked += 1;
                if theirs > own {
                    violations.push(format!(
                        "src/{}:{}: {module} imports the higher {used}: {line}",
                        rel.display(),
                        n + 1
                    ));
                }
            }
        }
    }
    assert!(checked > 50, "only {checked} crate:: paths were checked: is the scan reading the sources?");
    assert!(violations.is_empty(), "upward imports:\n{}", violations.join("\n"));
}

/// The sibling files (of one folder, `mod.rs` aside) that `text` imports:
/// through `super::NAME` or `crate::<folder path>::NAME`.
fn sibling_imports(text: &str, folder: &str, siblings: &[String]) -> Vec<String> {
    let crate_prefix = format!("crate::{}::", folder.replace('/', "::"));
    let mut found = Vec::new();
    for line in text.lines().map(str::trim).filter(|l| l.starts_with("use ") || l.starts_with("pub use ")) {
        for prefix in ["super::", crate_prefix.as_str()] {
            for (i, _) in line.match_indices(prefix) {
                let name: String =
                    line[i + prefix.len()..].chars().take_while(|c| c.is_ascii_alphanumeric() || *c == '_').collect();
                if siblings.contains(&name) && !found.contains(&name) {
                    found.push(name);
                }
            }
        }
    }
    found
}

#[test]
fn no_two_files_of_a_folder_import_each_other() {
    // Mechanics are one file each and data flows one way between them: a
    // pair that imports each other is one concept split in two (before:
    // plan/confounders.rs and plan/interventions.rs).
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let mut folders: std::collections::BTreeMap<PathBuf, Vec<String>> = Default::default();
    for file in &files {
        let stem = file.file_stem().unwrap().to_string_lossy().into_owned();
        if file.parent() != Some(src.as_path()) && stem != "mod" {
            folders.entry(file.parent().unwrap().to_path_buf()).or_default().push(stem);
        }
    }
    let (mut pairs_checked, mut cycles) = (0, Vec::new());
    for (folder, siblings) in &folders {
        let rel = folder.strip_prefix(&src).unwrap().to_string_lossy().into_owned();
        let imports: Vec<(String, Vec<String>)> = siblings
            .iter()
            .map(|s| {
                (
                    s.clone(),
                    sibling_imports(&std::fs::read_to_string(folder.join(format!("{s}.rs"))).unwrap(), &rel, siblings),
                )
            })
            .collect();
        for (a, theirs) in &imports {
            for b in theirs {
                pairs_checked += 1;
                let back = imports.iter().find(|(n, _)| n == b).is_some_and(|(_, i)| i.contains(a));
                if back && a < b {
                    cycles.push(format!("src/{rel}/{a}.rs <-> src/{rel}/{b}.rs"));
                }
            }
        }
    }
    assert!(pairs_checked > 10, "only {pairs_checked} sibling imports found: is the scan reading the sources?");
    assert!(cycles.is_empty(), "files that import each other:\n{}", cycles.join("\n"));
}
