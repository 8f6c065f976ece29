//! Keeps the documents true (issue 38): the README stays a short guide whose
//! tour runs, every relative link in the documents resolves, the command-line
//! reference in the guide is the program's own `--help`, and the performance
//! page stays today's figures rather than a log.

use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn read(rel: &str) -> String {
    std::fs::read_to_string(root().join(rel)).unwrap_or_else(|e| panic!("{rel}: {e}"))
}

/// The README's most lines: a pitch, two commands, a tour and links; the
/// reference lives in `docs/guide/`.
const README_MAX_LINES: usize = 200;
/// `docs/PERFORMANCE.md`'s most lines: one table per stage; history goes to
/// `docs/notebook/`.
const PERFORMANCE_MAX_LINES: usize = 300;

#[test]
fn the_readme_and_the_performance_page_stay_short() {
    let readme = read("README.md").lines().count();
    assert!(
        readme <= README_MAX_LINES,
        "README.md has {readme} lines (at most {README_MAX_LINES}): move reference material to docs/guide/"
    );
    let perf = read("docs/PERFORMANCE.md").lines().count();
    assert!(
        perf <= PERFORMANCE_MAX_LINES,
        "docs/PERFORMANCE.md has {perf} lines (at most {PERFORMANCE_MAX_LINES}): dated experiments go to docs/notebook/"
    );
}

/// Fenced code blocks of a markdown text: `(info string, body)`.
fn fenced_blocks(text: &str) -> Vec<(String, String)> {
    let mut out = Vec::new();
    let mut open: Option<(String, String)> = None;
    for line in text.lines() {
        let trimmed = line.trim_start();
        match &mut open {
            None if trimmed.starts_with("```") => open = Some((trimmed[3..].trim().to_string(), String::new())),
            Some(_) if trimmed.starts_with("```") => out.push(open.take().unwrap()),
            Some((_, body)) => {
                body.push_str(line);
                body.push('\n');
            }
            None => {}
        }
    }
    out
}

/// The text of a markdown file with fenced blocks and inline code removed,
/// so that examples in code are not taken for links.
fn prose(text: &str) -> String {
    let mut out = String::new();
    let mut in_fence = false;
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            in_fence = !in_fence;
            continue;
        }
        if in_fence {
            continue;
        }
        // Drop `inline code` spans.
        let mut ticked = false;
        for c in line.chars() {
            if c == '`' {
                ticked = !ticked;
            } else if !ticked {
                out.push(c);
            }
        }
        out.push('\n');
    }
    out
}

/// Targets of the inline links and images of a markdown text: `[t](x)`, `![t](x)`.
fn link_targets(text: &str) -> Vec<String> {
    let text = prose(text);
    let mut out = Vec::new();
    let bytes = text.as_bytes();
    let mut i = 0;
    while let Some(at) = text[i..].find("](") {
        let start = i + at + 2;
        let mut depth = 0usize;
        let mut end = start;
        while end < bytes.len() {
            match bytes[end] {
                b'(' => depth += 1,
                b')' if depth == 0 => break,
                b')' => depth -= 1,
                b'\n' => break,
                _ => {}
            }
            end += 1;
        }
        let target = text[start..end].split_whitespace().next().unwrap_or("").to_string();
        out.push(target);
        i = end.max(start);
    }
    out
}

fn markdown_files() -> Vec<PathBuf> {
    fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            let name = path.file_name().unwrap().to_string_lossy().to_string();
            if path.is_dir() {
                // The built book (docs/guide/book) is output, not source.
                if name != "book" && !name.starts_with('.') {
                    walk(&path, out);
                }
            } else if name.ends_with(".md") {
                out.push(path);
            }
        }
    }
    let mut out = Vec::new();
    for file in ["README.md", "ARCHITECTURE.md"] {
        out.push(root().join(file));
    }
    for dir in ["docs", "format-spec", "scenes", "tools", "tests/data"] {
        if root().join(dir).is_dir() {
            walk(&root().join(dir), &mut out);
        }
    }
    out
}

#[test]
fn every_relative_link_in_the_documents_resolves() {
    let mut checked = 0;
    let mut broken = Vec::new();
    for file in markdown_files() {
        let text = std::fs::read_to_string(&file).unwrap();
        for target in link_targets(&text) {
            if target.is_empty() || target.starts_with('#') || target.contains("://") || target.starts_with("mailto:") {
                continue;
            }
            let path = target.split('#').next().unwrap();
            let resolved = file.parent().unwrap().join(path);
            checked += 1;
            if !resolved.exists() {
                broken.push(format!("{}: ({target}) does not exist", file.strip_prefix(root()).unwrap().display()));
            }
        }
    }
    assert!(checked > 100, "only {checked} links found: is the link scanner broken?");
    assert!(broken.is_empty(), "broken links:\n{}", broken.join("\n"));
}

#[test]
fn the_link_scanner_finds_links_and_skips_code() {
    let text =
        "see [a](x.md) and ![b](img/p.png \"title\")\n`[not](code.md)`\n```\n[no](fence.md)\n```\n[c](y.md#part)";
    assert_eq!(link_targets(text), ["x.md", "img/p.png", "y.md#part"]);
}

/// The tour's commands: every line beginning with `illumnet ` in the `sh`
/// blocks after the first (the first holds the two top commands, `cargo run
/// … demo` and the test script, which CI runs by other means).
fn tour_commands(readme: &str) -> Vec<Vec<String>> {
    fenced_blocks(readme)
        .into_iter()
        .filter(|(info, _)| info == "sh")
        .skip(1)
        .flat_map(|(_, body)| body.lines().map(str::to_string).collect::<Vec<_>>())
        .filter_map(|line| {
            line.strip_prefix("illumnet ").map(|rest| rest.split_whitespace().map(str::to_string).collect())
        })
        .collect()
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let path = entry.unwrap().path();
        let dest = to.join(path.file_name().unwrap());
        if path.is_dir() {
            copy_dir(&path, &dest);
        } else {
            std::fs::copy(&path, &dest).unwrap();
        }
    }
}

/// Every command of the README's tour runs and succeeds, in order, from a
/// folder holding the repository's scenes and test data (as the README says:
/// run from the root), so the tour cannot rot.
#[test]
fn the_readme_tour_runs() {
    let commands = tour_commands(&read("README.md"));
    assert!(
        commands.len() >= 8,
        "the tour has {} commands: is the README's tour still in ```sh blocks?",
        commands.len()
    );
    let dir = tempfile::tempdir().unwrap();
    copy_dir(&root().join("scenes"), &dir.path().join("scenes"));
    copy_dir(&root().join("tests/data"), &dir.path().join("tests/data"));
    for args in &commands {
        let out = Command::new(env!("CARGO_BIN_EXE_illumnet"))
            .args(args)
            .current_dir(dir.path())
            .env("HOME", dir.path())
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "README tour: `illumnet {}` failed ({}):\n{}",
            args.join(" "),
            out.status,
            String::from_utf8_lossy(&out.stderr)
        );
    }
    // The tour's last build is the same archive as its first, under a budget.
    let (a, b) = (dir.path().join("tour/box.inet"), dir.path().join("tour/bounded.inet"));
    if a.exists() && b.exists() {
        assert!(
            std::fs::read(a).unwrap() == std::fs::read(b).unwrap(),
            "README tour: the budgeted build differs from the plain one"
        );
    }
}

const CLI_REFERENCE: &str = "docs/guide/src/cli.md";

/// The subcommands `illumnet help` lists.
fn subcommands(help: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut in_list = false;
    for line in help.lines() {
        if line.starts_with("Commands:") {
            in_list = true;
        } else if in_list && line.starts_with("  ") {
            let name = line.split_whitespace().next().unwrap().to_string();
            if name != "help" {
                out.push(name);
            }
        } else if in_list {
            break;
        }
    }
    out
}

fn help_of(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_illumnet")).args(args).output().unwrap();
    assert!(out.status.success(), "illumnet {}: {}", args.join(" "), String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).unwrap()
}

/// The command-line reference as generated from the program's help.
fn cli_reference() -> String {
    let top = help_of(&["help"]);
    let mut md = String::from(
        "<!-- generated: do not edit; tests/docs.rs writes it (UPDATE_CLI_REFERENCE=1 cargo test --test docs) -->\n\
         # Command-line reference\n\n\
         Every command's `--help`, as the program prints it (`illumnet help COMMAND`). \
         Generated from the program's own argument definitions; a test fails when this page \
         and the program disagree.\n\n## illumnet\n\n```text\n",
    );
    md.push_str(&top);
    md.push_str("```\n");
    for cmd in subcommands(&top) {
        md.push_str(&format!("\n## illumnet {cmd}\n\n```text\n"));
        md.push_str(&help_of(&["help", &cmd]));
        md.push_str("```\n");
    }
    md
}

/// `docs/guide/src/cli.md` is the program's help, word for word: a change to
/// an option's doc comment that is not carried to the guide fails here.
#[test]
fn the_cli_reference_is_the_programs_help() {
    let want = cli_reference();
    assert!(want.matches("\n## illumnet ").count() >= 7, "too few commands in the help: {want}");
    let path = root().join(CLI_REFERENCE);
    if std::env::var_os("UPDATE_CLI_REFERENCE").is_some() {
        std::fs::write(&path, &want).unwrap();
        return;
    }
    let have = std::fs::read_to_string(&path).unwrap_or_default();
    if have != want {
        let line = have
            .lines()
            .zip(want.lines())
            .position(|(a, b)| a != b)
            .unwrap_or(have.lines().count().min(want.lines().count()));
        panic!(
            "{CLI_REFERENCE} differs from the program's help from line {}:\n  page:    {:?}\n  program: {:?}\nregenerate it: UPDATE_CLI_REFERENCE=1 cargo test --test docs the_cli_reference",
            line + 1,
            have.lines().nth(line).unwrap_or(""),
            want.lines().nth(line).unwrap_or("")
        );
    }
}
