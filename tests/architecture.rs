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
    let text = "use crate::archive::{self, X};\nuse crate::{geometry::Primitive, patch};\nfn f() { crate::bake::go() }\n#[cfg(test)]\nmod tests { use crate::scene; }";
    let got: Vec<String> = used_modules(text).into_iter().collect();
    assert_eq!(got, ["archive", "bake", "geometry", "patch"]);
}

// ---------------------------------------------------------------------------
// Room sizes and import circles (issue 38): parsed with `syn`, so strings,
// comments and macros cannot fool the counts.

/// The longest a file in `src/` may be, in lines (tests included: a test
/// module that grows past it moves to a file of its own).
const MAX_FILE_LINES: usize = 800;
/// The longest a function outside tests may be, in lines from `fn` to its
/// closing brace.
const MAX_FN_LINES: usize = 120;

/// `#[test]`, `#[cfg(test)]` (and `#[cfg(all(test, …))]`) items are tests.
fn is_test(attrs: &[syn::Attribute]) -> bool {
    attrs.iter().any(|a| {
        let p = a.path();
        if p.is_ident("test") {
            return true;
        }
        if p.is_ident("cfg") {
            let syn::Meta::List(list) = &a.meta else { return false };
            let text = list.tokens.to_string();
            return text.contains("test") && !text.contains("not");
        }
        false
    })
}

fn line_span(start: proc_macro2::Span, end: proc_macro2::Span) -> usize {
    end.end().line - start.start().line + 1
}

/// Every function (free, inherent, trait default) outside tests, with its
/// length in lines: `(name, first line, lines)`.
fn long_functions(file: &syn::File) -> Vec<(String, usize, usize)> {
    use syn::spanned::Spanned;
    type Found = Vec<(String, usize, usize)>;
    fn record(out: &mut Found, sig: &syn::Signature, body: &syn::Block) {
        out.push((
            sig.ident.to_string(),
            sig.span().start().line,
            line_span(sig.fn_token.span, body.brace_token.span.close()),
        ));
    }
    fn walk(items: &[syn::Item], out: &mut Found) {
        for item in items.iter() {
            match item {
                syn::Item::Fn(f) if !is_test(&f.attrs) => record(out, &f.sig, &f.block),
                syn::Item::Impl(imp) if !is_test(&imp.attrs) => {
                    for it in &imp.items {
                        if let syn::ImplItem::Fn(f) = it
                            && !is_test(&f.attrs)
                        {
                            record(out, &f.sig, &f.block);
                        }
                    }
                }
                syn::Item::Trait(t) if !is_test(&t.attrs) => {
                    for it in &t.items {
                        if let syn::TraitItem::Fn(f) = it
                            && let Some(block) = &f.default
                        {
                            record(out, &f.sig, block);
                        }
                    }
                }
                syn::Item::Mod(m) if !is_test(&m.attrs) => {
                    if let Some((_, inner)) = &m.content {
                        walk(inner, out);
                    }
                }
                _ => {}
            }
        }
    }
    let mut out = Vec::new();
    walk(&file.items, &mut out);
    out
}

/// A file's module path from `src/`: `archive/links.rs` → `["archive",
/// "links"]`, `archive/mod.rs` → `["archive"]`, `lib.rs` → `[]`.
fn module_path(rel: &Path) -> Vec<String> {
    let mut parts: Vec<String> = rel.components().map(|c| c.as_os_str().to_string_lossy().into_owned()).collect();
    let last = parts.pop().unwrap();
    let stem = last.trim_end_matches(".rs");
    if stem != "mod" && stem != "lib" && stem != "main" {
        parts.push(stem.to_string());
    }
    parts
}

/// The paths a file's non-test code names (`use` trees flattened, and every
/// path in types and expressions), as segment lists.
fn named_paths(file: &syn::File) -> Vec<Vec<String>> {
    use syn::visit::Visit;
    struct Names(Vec<Vec<String>>);
    fn flatten(tree: &syn::UseTree, prefix: &mut Vec<String>, out: &mut Vec<Vec<String>>) {
        match tree {
            syn::UseTree::Path(p) => {
                prefix.push(p.ident.to_string());
                flatten(&p.tree, prefix, out);
                prefix.pop();
            }
            syn::UseTree::Name(n) => {
                let mut full = prefix.clone();
                if n.ident != "self" {
                    full.push(n.ident.to_string());
                }
                out.push(full);
            }
            syn::UseTree::Rename(r) => {
                let mut full = prefix.clone();
                full.push(r.ident.to_string());
                out.push(full);
            }
            syn::UseTree::Glob(_) => out.push(prefix.clone()),
            syn::UseTree::Group(g) => g.items.iter().for_each(|t| flatten(t, prefix, out)),
        }
    }
    impl<'a> Visit<'a> for Names {
        fn visit_item_use(&mut self, u: &'a syn::ItemUse) {
            if !is_test(&u.attrs) {
                flatten(&u.tree, &mut Vec::new(), &mut self.0);
            }
        }
        fn visit_path(&mut self, p: &'a syn::Path) {
            self.0.push(p.segments.iter().map(|s| s.ident.to_string()).collect());
            syn::visit::visit_path(self, p);
        }
        fn visit_item_mod(&mut self, m: &'a syn::ItemMod) {
            if !is_test(&m.attrs) {
                syn::visit::visit_item_mod(self, m);
            }
        }
        fn visit_item_fn(&mut self, f: &'a syn::ItemFn) {
            if !is_test(&f.attrs) {
                syn::visit::visit_item_fn(self, f);
            }
        }
        fn visit_item_impl(&mut self, i: &'a syn::ItemImpl) {
            if !is_test(&i.attrs) {
                syn::visit::visit_item_impl(self, i);
            }
        }
    }
    let mut names = Names(Vec::new());
    names.visit_file(file);
    names.0
}

struct SourceTree {
    /// Module path → file (relative to `src/`).
    files: BTreeMap<Vec<String>, PathBuf>,
    parsed: BTreeMap<Vec<String>, (syn::File, usize)>,
}

fn source_tree() -> SourceTree {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut paths = Vec::new();
    rust_files(&root, &mut paths);
    let mut files = BTreeMap::new();
    let mut parsed = BTreeMap::new();
    for path in paths {
        let rel = path.strip_prefix(&root).unwrap().to_path_buf();
        if rel == Path::new("main.rs") || rel.starts_with("cli") {
            // The binary's modules form a tree of their own under `main`.
            let mut m = vec!["<bin>".to_string()];
            m.extend(module_path(&rel).into_iter().filter(|s| s != "main"));
            let text = std::fs::read_to_string(&path).unwrap();
            let lines = text.lines().count();
            parsed.insert(
                m.clone(),
                (syn::parse_file(&text).unwrap_or_else(|e| panic!("{}: {e}", rel.display())), lines),
            );
            files.insert(m, rel);
            continue;
        }
        let m = module_path(&rel);
        let text = std::fs::read_to_string(&path).unwrap();
        let lines = text.lines().count();
        parsed.insert(m.clone(), (syn::parse_file(&text).unwrap_or_else(|e| panic!("{}: {e}", rel.display())), lines));
        files.insert(m, rel);
    }
    SourceTree { files, parsed }
}

impl SourceTree {
    /// The file module a path named in module `from` lands in, if any.
    fn resolve(&self, from: &[String], path: &[String]) -> Option<Vec<String>> {
        let crate_root: Vec<String> =
            if from.first().is_some_and(|s| s == "<bin>") { vec!["<bin>".into()] } else { vec![] };
        let mut abs: Vec<String>;
        let mut rest = path;
        match path.first().map(String::as_str) {
            Some("crate") => {
                abs = crate_root;
                rest = &path[1..];
            }
            Some("super") => {
                abs = from.to_vec();
                while rest.first().is_some_and(|s| s == "super") {
                    abs.pop();
                    rest = &rest[1..];
                }
            }
            Some("self") => {
                abs = from.to_vec();
                rest = &path[1..];
            }
            Some("illumnet") if crate_root.len() == 1 => {
                abs = vec![];
                rest = &path[1..];
            }
            Some(first) => {
                let mut child = from.to_vec();
                child.push(first.to_string());
                if !self.files.contains_key(&child) {
                    return None;
                }
                abs = from.to_vec();
            }
            None => return None,
        }
        abs.extend(rest.iter().cloned());
        // The longest prefix that is a file module.
        (0..=abs.len()).rev().map(|n| abs[..n].to_vec()).find(|m| self.files.contains_key(m))
    }

    /// File-to-file uses, leaving out a module's uses of its ancestors (a
    /// folder's `mod.rs` is the floor its files stand on).
    fn edges(&self) -> BTreeMap<Vec<String>, BTreeSet<Vec<String>>> {
        let mut out: BTreeMap<Vec<String>, BTreeSet<Vec<String>>> = BTreeMap::new();
        for (module, (file, _)) in &self.parsed {
            let set = out.entry(module.clone()).or_default();
            for path in named_paths(file) {
                if let Some(target) = self.resolve(module, &path)
                    && &target != module
                    && !module.starts_with(&target)
                {
                    set.insert(target);
                }
            }
        }
        out
    }
}

/// Strongly connected components of more than one file (Tarjan).
fn circles(edges: &BTreeMap<Vec<String>, BTreeSet<Vec<String>>>) -> Vec<Vec<Vec<String>>> {
    struct State<'a> {
        edges: &'a BTreeMap<Vec<String>, BTreeSet<Vec<String>>>,
        index: BTreeMap<&'a Vec<String>, usize>,
        low: BTreeMap<&'a Vec<String>, usize>,
        stack: Vec<&'a Vec<String>>,
        on_stack: BTreeSet<&'a Vec<String>>,
        out: Vec<Vec<Vec<String>>>,
    }
    fn visit<'a>(s: &mut State<'a>, v: &'a Vec<String>) {
        let i = s.index.len();
        s.index.insert(v, i);
        s.low.insert(v, i);
        s.stack.push(v);
        s.on_stack.insert(v);
        for w in s.edges.get(v).into_iter().flatten() {
            let Some((w, _)) = s.edges.get_key_value(w) else { continue };
            if !s.index.contains_key(w) {
                visit(s, w);
                let lw = s.low[w];
                let lv = s.low.get_mut(v).unwrap();
                *lv = (*lv).min(lw);
            } else if s.on_stack.contains(w) {
                let iw = s.index[w];
                let lv = s.low.get_mut(v).unwrap();
                *lv = (*lv).min(iw);
            }
        }
        if s.low[v] == s.index[v] {
            let mut comp = Vec::new();
            loop {
                let w = s.stack.pop().unwrap();
                s.on_stack.remove(w);
                comp.push(w.clone());
                if w == v {
                    break;
                }
            }
            if comp.len() > 1 {
                comp.sort();
                s.out.push(comp);
            }
        }
    }
    let mut s = State {
        edges,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on_stack: BTreeSet::new(),
        out: Vec::new(),
    };
    for v in edges.keys() {
        if !s.index.contains_key(v) {
            visit(&mut s, v);
        }
    }
    s.out
}

#[test]
fn no_file_in_src_is_over_800_lines_and_no_function_over_120() {
    let tree = source_tree();
    let mut problems = Vec::new();
    for (module, (file, lines)) in &tree.parsed {
        let rel = tree.files[module].display();
        if *lines > MAX_FILE_LINES {
            problems.push(format!("src/{rel}: {lines} lines (at most {MAX_FILE_LINES})"));
        }
        for (name, line, len) in long_functions(file) {
            if len > MAX_FN_LINES {
                problems
                    .push(format!("src/{rel}:{line}: fn {name} is {len} lines (at most {MAX_FN_LINES} outside tests)"));
            }
        }
    }
    assert!(problems.is_empty(), "rooms too big to see:\n{}", problems.join("\n"));
}

#[test]
fn no_import_circle_between_files() {
    let tree = source_tree();
    let found = circles(&tree.edges());
    let show = |c: &Vec<Vec<String>>| {
        c.iter().map(|m| format!("src/{}", tree.files[m].display())).collect::<Vec<_>>().join(" ↔ ")
    };
    assert!(
        found.is_empty(),
        "files that import each other in a circle:\n{}",
        found.iter().map(show).collect::<Vec<_>>().join("\n")
    );
}

#[test]
fn the_room_checks_can_fail() {
    // A function of 121 lines, one of test code, and a circle of two files.
    let body = "    let x = 1;\n".repeat(119);
    let text = format!("fn long() {{\n{body}}}\n#[cfg(test)]\nmod tests {{ fn longer() {{\n{body}{body}}} }}\n");
    let file = syn::parse_file(&text).unwrap();
    let found: Vec<_> = long_functions(&file).into_iter().map(|(n, _, l)| (n, l)).collect();
    assert_eq!(found, [("long".to_string(), 121)]);
    let a = vec!["m".to_string(), "a".to_string()];
    let b = vec!["m".to_string(), "b".to_string()];
    let c = vec!["m".to_string(), "c".to_string()];
    let edges = BTreeMap::from([
        (a.clone(), BTreeSet::from([b.clone()])),
        (b.clone(), BTreeSet::from([a.clone(), c.clone()])),
        (c.clone(), BTreeSet::new()),
    ]);
    assert_eq!(circles(&edges), vec![vec![a, b]]);
}
