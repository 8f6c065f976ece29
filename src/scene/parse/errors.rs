//! Errors located in TOML text: [`Ctx`] turns a byte span into line and
//! column, names the field at a position from the table headers and keys
//! above it (the TOML parser gives only a position), and words the
//! parser's own messages plainly (no Rust type names).

use std::ops::Range;
use std::path::Path;

use crate::scene::SceneError;

/// The text being read and its file: what an error needs to say where.
pub(super) struct Ctx<'a> {
    pub(super) text: &'a str,
    pub(super) file: &'a Path,
}

impl Ctx<'_> {
    /// The text as `T`, a TOML error naming its line, column and field
    /// in plain words.
    pub(super) fn deserialize<T: serde::de::DeserializeOwned>(&self) -> Result<T, SceneError> {
        toml::from_str(self.text).map_err(|e| {
            let span = e.span().unwrap_or(0..0);
            let field = field_at(self.text, span.start);
            let key = field.rsplit(['.', ']']).next().unwrap_or("").to_string();
            self.err(span, field, plain_message(e.message().trim(), &key))
        })
    }

    /// An error at byte range `span` of the text, naming `field`.
    pub(super) fn err(&self, span: Range<usize>, field: impl Into<String>, message: impl Into<String>) -> SceneError {
        let (line, column) = line_col(self.text, span.start);
        SceneError {
            file: self.file.into(),
            line,
            column,
            field: field.into(),
            message: message.into(),
            unreadable: false,
        }
    }
}

fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let offset = offset.min(text.len());
    let before = &text.as_bytes()[..offset];
    let line = before.iter().filter(|&&b| b == b'\n').count() + 1;
    let column = offset - before.iter().rposition(|&b| b == b'\n').map_or(0, |p| p + 1) + 1;
    (line, column)
}

/// The dotted path of the key whose value is at byte `offset` of `text`
/// (e.g. `surface[2].box.min`), from the table headers above it and the
/// keys on its line; empty when none is found. The TOML parser's errors
/// give a position only, and users look for a field.
fn field_at(text: &str, offset: usize) -> String {
    let offset = offset.min(text.len());
    let line_start = text[..offset].rfind('\n').map_or(0, |p| p + 1);
    // The table header in force, with the index of array tables.
    let mut header = String::new();
    let mut counts: Vec<(String, usize)> = Vec::new();
    // Brackets open at the start of each line (outside strings and
    // comments): a line inside a multi-line array is no table header.
    let mut depth = 0i32;
    // The line of the last key that began outside any bracket: the one a
    // value continued over several lines belongs to.
    let mut outer_start = 0..0;
    let mut at = 0;
    for raw in text[..line_start].split_inclusive('\n') {
        let (line, start) = (raw.trim(), at);
        at += raw.len();
        let open = depth;
        if open == 0
            && let Some((k, _)) = line.split_once('=')
            && !k.trim().is_empty()
            && k.trim().chars().all(|c| c.is_alphanumeric() || c == '_' || c == '-' || c == '.' || c == ' ')
        {
            outer_start = start..at;
        }
        for c in code_chars(line) {
            match c {
                '[' | '{' => depth += 1,
                ']' | '}' => depth -= 1,
                _ => {}
            }
        }
        if open > 0 {
            continue;
        }
        // A header line's own brackets balance.
        if line.starts_with('[') {
            depth = 0;
        }
        if let Some(name) = line.strip_prefix("[[").and_then(|l| l.split("]]").next()) {
            let name = name.trim().to_string();
            let n = match counts.iter_mut().find(|(k, _)| *k == name) {
                Some((_, n)) => {
                    *n += 1;
                    *n
                }
                None => {
                    counts.push((name.clone(), 0));
                    0
                }
            };
            header = format!("{name}[{n}]");
        } else if let Some(name) = line.strip_prefix('[').and_then(|l| l.split(']').next()) {
            header = name.trim().to_string();
        }
    }
    // Keys on the line up to the offset, nested by inline tables and
    // arrays (an inline table in an array is named by its index); if none
    // comes before it (a duplicate key is reported at the line's start),
    // the line's first key; if the line has none (a value continued from
    // the line above), the nearest key above.
    let keys = |segment: &str| {
        let mut p = KeyPath::default();
        p.feed(segment);
        p.path(None, false)
    };
    let line_end = text[offset..].find('\n').map_or(text.len(), |p| offset + p);
    // The error is in a table header itself (a table given twice).
    if depth <= 0
        && let Some(name) = text[line_start..line_end].trim().strip_prefix('[')
    {
        return name.trim_start_matches('[').split(']').next().unwrap_or("").trim().to_string();
    }
    // A key that starts at the offset (an unknown field is reported at
    // its key) names the field itself.
    let word: String =
        text[offset..].chars().take_while(|&c| c.is_alphanumeric() || c == '_' || c == '-' || c == '.').collect();
    let at_key = (!word.is_empty() && text[offset + word.len()..].trim_start().starts_with('=')).then_some(word);
    // An error about a whole inline table (a field it lacks) is reported
    // at its brace.
    let at_table = text[offset..].starts_with('{');
    let mut path = if depth > 0 && !outer_start.is_empty() {
        // Inside a value continued from above: the path from its key on,
        // line by line.
        let mut p = KeyPath::default();
        for line in text[outer_start.start..offset].split_inclusive('\n') {
            p.feed(line);
        }
        p.path(at_key.clone(), at_table)
    } else {
        let mut p = KeyPath::default();
        p.feed(&text[line_start..offset]);
        p.path(at_key.clone(), at_table)
    };
    if path.is_empty() {
        path = keys(&text[line_start..line_end]).into_iter().take(1).collect();
    }
    if path.is_empty() {
        path = text[..line_start]
            .lines()
            .rev()
            .take_while(|l| !l.trim_start().starts_with('['))
            .map(keys)
            .find(|k| !k.is_empty())
            .map(|k| k.into_iter().take(1).collect())
            .unwrap_or_default();
    }
    let tail = path.join(".");
    match (header.is_empty(), tail.is_empty()) {
        (true, _) => tail,
        (false, true) => header,
        (false, false) => format!("{header}.{tail}"),
    }
}

/// Where a position in TOML text lies among the inline tables and arrays
/// of a value, fed the text before it line by line.
#[derive(Default)]
struct KeyPath {
    /// Open inline tables (named by their key; empty: an array's element)
    /// and arrays (their key and the element at hand).
    open: Vec<(String, Option<usize>)>,
    /// The key whose value is being read.
    last: Option<String>,
    word: String,
}

impl KeyPath {
    fn feed(&mut self, line: &str) {
        for c in code_chars(line) {
            match c {
                // A dotted key (`camera.width`) is one path; a number's
                // dot never reaches a key (only a word before `=` does).
                c if c.is_alphanumeric() || c == '_' || c == '-' || c == '.' => self.word.push(c),
                '=' => {
                    if !self.word.is_empty() {
                        self.last = Some(std::mem::take(&mut self.word));
                    }
                }
                '{' | '[' => {
                    self.word.clear();
                    let key = self.last.take().unwrap_or_default();
                    self.open.push((key, (c == '[').then_some(0)));
                }
                '}' | ']' => {
                    self.word.clear();
                    self.open.pop();
                    self.last = None;
                }
                ',' => {
                    self.word.clear();
                    if let Some((_, Some(i))) = self.open.last_mut() {
                        *i += 1;
                    }
                }
                c if c.is_whitespace() => {}
                _ => self.word.clear(),
            }
        }
    }

    /// The keys down to the position (`key`: one that starts there;
    /// `at_table`: an inline table starts there): an array holding inline
    /// tables gives its element's index.
    fn path(&self, key: Option<String>, at_table: bool) -> Vec<String> {
        let mut out = Vec::new();
        for (i, (k, element)) in self.open.iter().enumerate() {
            let table_inside = self.open.get(i + 1).map_or(at_table, |n| n.1.is_none());
            match element {
                Some(e) if table_inside && !k.is_empty() => out.push(format!("{k}[{e}]")),
                _ if !k.is_empty() => out.push(k.clone()),
                _ => {}
            }
        }
        // A key that starts at the position after a dotted prefix
        // (`camera.` of `camera.fovv`) is named with it.
        let key = key.map(|k| if self.word.ends_with('.') { format!("{}{k}", self.word) } else { k });
        out.extend(key.or_else(|| self.last.clone()));
        out
    }
}

/// The characters of a TOML line outside strings (each string stands as
/// one `"`) up to a `#` comment.
fn code_chars(line: &str) -> impl Iterator<Item = char> + '_ {
    let (mut quote, mut escaped) = (None, false);
    line.chars()
        .filter_map(move |c| match (quote, c) {
            // A basic string's escape (`\"`, `\\`): the next character is
            // the string's.
            (Some('"'), _) if escaped => {
                escaped = false;
                None
            }
            (Some('"'), '\\') => {
                escaped = true;
                None
            }
            (Some(q), c) if c == q => {
                quote = None;
                None
            }
            (Some(_), _) => None,
            (None, '"' | '\'') => {
                quote = Some(c);
                Some('"')
            }
            _ => Some(c),
        })
        .take_while(|&c| c != '#')
}

/// The TOML parser's message in plain words: no Rust type names.
fn plain_message(message: &str, key: &str) -> String {
    if message == "duplicate key" {
        return if key.is_empty() { "a key is given twice".into() } else { format!("`{key}` is given twice") };
    }
    let words = |expected: &str| -> String {
        let e = expected.trim();
        match e {
            "u8" | "u16" | "u32" | "u64" | "usize" | "i32" | "i64" => "a whole number".into(),
            "f32" | "f64" => "a number".into(),
            "a sequence" => "a list in brackets, like [1, 2, 3]".into(),
            "a boolean" => "true or false".into(),
            "a string" => "a quoted string".into(),
            _ if e.starts_with("an array of length ") => {
                format!("a list of {} numbers, like [1, 2, 3]", e.trim_start_matches("an array of length "))
            }
            _ if e.starts_with("struct ") || e == "a map" || e.starts_with("a map") => "a table".into(),
            _ => e.to_string(),
        }
    };
    if let Some(rest) = message.strip_prefix("invalid length ")
        && let Some((got, expected)) = rest.split_once(", expected ")
    {
        return format!("expected {}, got {got} values", words(expected));
    }
    // A whole number out of its type's range.
    if let Some(rest) = message.strip_prefix("invalid value: integer ")
        && let Some((got, expected)) = rest.split_once(", expected ")
    {
        let range = match expected.trim() {
            "u8" => " from 0 to 255",
            "u16" => " from 0 to 65535",
            "u32" => " from 0 to 4294967295",
            "i32" => " from -2147483648 to 2147483647",
            _ => "",
        };
        let got = got.replace('`', "");
        if got.starts_with('-') && expected.trim().starts_with('u') {
            return format!("expected {}, not a negative one, got {got}", words(expected));
        }
        return format!("expected {}{range}, got {got}", words(expected));
    }
    if let Some(rest) = message.strip_prefix("invalid type: ")
        && let Some((got, expected)) = rest.split_once(", expected ")
    {
        let got = got
            .replace("floating point ", "")
            .replace("integer ", "")
            .replace("string ", "")
            .replace("boolean ", "")
            .replace('`', "");
        let got = match got.as_str() {
            "sequence" => "a list".to_string(),
            "map" => "a table".to_string(),
            other => other.to_string(),
        };
        return format!("expected {}, got {got}", words(expected));
    }
    message.to_string()
}
