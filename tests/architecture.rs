//! Keeps `ARCHITECTURE.md`'s code map true: every module of the library
//! uses (`crate::…`) only the modules its row's "may use" column names.
//! Unit-test modules (`#[cfg(test)] mod tests`) are left out: tests may
//! reach for whatever helps them check.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// `module → modules it may use`, from the code map's table rows
/// `| `name` | holds | may use |`; `None` for "everything".
fn allowed(architecture: &str) -> BTreeMap<String, Option<BTreeSet<String>>> {
    let ticked = |cell: &str| -> BTreeSet<String> {
        cell.split('`').skip(1).step_by(2).filter(|s| !s.contains(' ')).map(|s| s.to_string()).collect()
    };
    let mut out = BTreeMap::new();
    for line in architecture.lines() {
        let cells: Vec<&str> = line.split('|').map(str::trim).collect();
        // "", module, holds, may use, ""
        if cells.len() != 5 || !cells[1].starts_with('`') {
            continue;
        }
        let name = cells[1].split('`').nth(1).unwrap().to_string();
        let uses = if cells[3].contains("everything") { None } else { Some(ticked(cells[3])) };
        out.insert(name, uses);
    }
    out
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

/// The top-level modules a file's non-test code names as `crate::X`
/// (including `use crate::{X, Y::…}`).
fn used_modules(text: &str) -> BTreeSet<String> {
    let code = match text.find("#[cfg(test)]\nmod tests") {
        Some(i) => &text[..i],
        None => text,
    };
    let mut out = BTreeSet::new();
    let word = |s: &str| s.chars().take_while(|c| c.is_ascii_alphanumeric() || *c == '_').collect::<String>();
    for (i, _) in code.match_indices("crate::") {
        let rest = &code[i + "crate::".len()..];
        if let Some(group) = rest.strip_prefix('{') {
            let inner = &group[..group.find('}').unwrap_or(group.len())];
            out.extend(inner.split(',').map(|s| word(s.trim())).filter(|s| !s.is_empty()));
        } else {
            out.insert(word(rest));
        }
    }
    // `crate::NAME` in capitals is an item of the crate root, not a module.
    out.retain(|m| m.chars().next().is_some_and(|c| c.is_ascii_lowercase()));
    out
}

#[test]
fn modules_use_only_what_architecture_md_allows() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let map = allowed(&std::fs::read_to_string(root.join("ARCHITECTURE.md")).unwrap());
    assert!(map.len() >= 10, "code map table not found in ARCHITECTURE.md: {map:?}");
    let mut files = Vec::new();
    rust_files(&root.join("src"), &mut files);
    let mut problems = Vec::new();
    for file in &files {
        let rel = file.strip_prefix(root.join("src")).unwrap();
        let module = rel.components().next().unwrap().as_os_str().to_string_lossy().trim_end_matches(".rs").to_string();
        if module == "lib" || module == "main" {
            continue;
        }
        let Some(rule) = map.get(&module) else {
            problems.push(format!(
                "src/{} is in module `{module}`, which ARCHITECTURE.md's code map does not list",
                rel.display()
            ));
            continue;
        };
        let Some(may) = rule else { continue };
        let text = std::fs::read_to_string(file).unwrap();
        // Lines that are comments do not import.
        let code: String = text.lines().filter(|l| !l.trim_start().starts_with("//")).collect::<Vec<_>>().join("\n");
        for used in used_modules(&code) {
            if used != module && !may.contains(&used) {
                problems.push(format!(
                    "src/{} (module `{module}`) uses `{used}`, which its row does not allow",
                    rel.display()
                ));
            }
        }
    }
    assert!(problems.is_empty(), "ARCHITECTURE.md's import rules do not hold:\n{}", problems.join("\n"));
}

#[test]
fn the_import_scanner_sees_grouped_and_plain_uses() {
    let text = "use crate::archive::{self, X};\nuse crate::{geometry::Primitive, patch};\nfn f() { crate::build::go() }\n#[cfg(test)]\nmod tests { use crate::scene; }";
    let got: Vec<String> = used_modules(text).into_iter().collect();
    assert_eq!(got, ["archive", "build", "geometry", "patch"]);
}
