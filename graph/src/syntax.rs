//! A small RON reader that keeps the position of every value, and a printer.
//!
//! The `ron` crate deserialises into typed values but forgets where each value came from. The
//! engine needs positions for its errors and for `why`, so pipeline files are first read into a
//! [`Value`] tree in which every node carries an [`Origin`]; a node's `args` subtree is printed
//! back to RON text and handed to the kind's typed parser.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Where a value came from: a position in a pipeline file, a `--set` override, a sweep point,
/// or the engine itself.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Origin {
    /// A position in a file (1-based line and column).
    File {
        /// The file.
        path: Arc<Path>,
        /// Line, from 1.
        line: u32,
        /// Column (in characters), from 1.
        col: u32,
    },
    /// A `--set PATH=VALUE` override, kept verbatim.
    Set(Arc<str>),
    /// A sweep point's assignment (`aggregate.gamma=0.5`).
    Sweep(Arc<str>),
    /// Made by the engine (e.g. a repeat instance's `seed + i`), with a description.
    Engine(Arc<str>),
}

impl std::fmt::Display for Origin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Origin::File { path, line, col } => write!(f, "{}:{line}:{col}", path.display()),
            Origin::Set(s) => write!(f, "--set {s}"),
            Origin::Sweep(s) => write!(f, "sweep point {s}"),
            Origin::Engine(s) => f.write_str(s),
        }
    }
}

impl Origin {
    /// The folder relative paths written at this origin resolve against: the file's folder,
    /// or the current directory for command-line values.
    pub fn base_dir(&self) -> PathBuf {
        match self {
            Origin::File { path, .. } => path.parent().map(Path::to_path_buf).unwrap_or_default(),
            _ => std::env::current_dir().unwrap_or_default(),
        }
    }
}

/// A RON value with its origin.
#[derive(Clone, Debug)]
pub struct Value {
    /// The value.
    pub kind: ValueKind,
    /// Where it was written.
    pub origin: Origin,
}

/// The shapes of RON values.
#[derive(Clone, Debug)]
pub enum ValueKind {
    /// `()`.
    Unit,
    /// `true` / `false`.
    Bool(bool),
    /// A number, kept as written (so printing it back loses nothing).
    Num(String),
    /// A string.
    Str(String),
    /// A character literal.
    Char(char),
    /// `[a, b]`.
    List(Vec<Value>),
    /// `{ k: v }`.
    Map(Vec<(Value, Value)>),
    /// `(a: 1)` or `Name(a: 1)`.
    Struct(Option<String>, Vec<(String, Value)>),
    /// `(1, 2)`, `Some(1)`, `Name(1, 2)`.
    Tuple(Option<String>, Vec<Value>),
    /// A bare identifier: a unit enum variant, `None`, `inf`, `NaN`.
    Ident(String),
}

/// A syntax error at a position.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SyntaxError {
    /// Where.
    pub origin: Origin,
    /// What.
    pub message: String,
}

impl Value {
    /// A value made by the engine or the command line.
    pub fn new(kind: ValueKind, origin: Origin) -> Self {
        Value { kind, origin }
    }
    /// The fields of a struct value (`(a: 1)`); `()` counts as an empty struct.
    pub fn fields(&self) -> Option<&[(String, Value)]> {
        match &self.kind {
            ValueKind::Struct(_, f) => Some(f),
            ValueKind::Unit => Some(&[]),
            _ => None,
        }
    }
    /// The field `name` of a struct value.
    pub fn field(&self, name: &str) -> Option<&Value> {
        self.fields()?
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v)
    }
    /// The string inside a string value.
    pub fn as_str(&self) -> Option<&str> {
        match &self.kind {
            ValueKind::Str(s) => Some(s),
            _ => None,
        }
    }
    /// A short description of the value's shape, for error messages.
    pub fn describe(&self) -> &'static str {
        match &self.kind {
            ValueKind::Unit => "`()`",
            ValueKind::Bool(_) => "a boolean",
            ValueKind::Num(_) => "a number",
            ValueKind::Str(_) => "a string",
            ValueKind::Char(_) => "a character",
            ValueKind::List(_) => "a list",
            ValueKind::Map(_) => "a map",
            ValueKind::Struct(..) => "a struct",
            ValueKind::Tuple(..) => "a tuple or enum variant",
            ValueKind::Ident(_) => "an identifier",
        }
    }
    /// Replaces the origin of this value and every value inside it.
    pub fn with_origin_deep(mut self, origin: &Origin) -> Self {
        fn walk(v: &mut Value, o: &Origin) {
            v.origin = o.clone();
            match &mut v.kind {
                ValueKind::List(items) | ValueKind::Tuple(_, items) => {
                    items.iter_mut().for_each(|i| walk(i, o))
                }
                ValueKind::Map(entries) => entries.iter_mut().for_each(|(k, v)| {
                    walk(k, o);
                    walk(v, o)
                }),
                ValueKind::Struct(_, fields) => fields.iter_mut().for_each(|(_, v)| walk(v, o)),
                _ => {}
            }
        }
        walk(&mut self, origin);
        self
    }
    /// Compact RON text of the value.
    pub fn to_ron(&self) -> String {
        let mut s = String::new();
        write_value(&mut s, self, None, 0);
        s
    }
    /// Indented RON text of the value.
    pub fn to_ron_pretty(&self, indent: usize) -> String {
        let mut s = String::new();
        write_value(&mut s, self, Some(indent), indent);
        s
    }
}

fn write_str_lit(out: &mut String, s: &str) {
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\r' => out.push_str("\\r"),
            '\t' => out.push_str("\\t"),
            c if (c as u32) < 0x20 => {
                let _ = write!(out, "\\u{{{:x}}}", c as u32);
            }
            c => out.push(c),
        }
    }
    out.push('"');
}

fn write_value(out: &mut String, v: &Value, pretty: Option<usize>, level: usize) {
    let nl = |out: &mut String, lvl: usize| {
        if pretty.is_some() {
            out.push('\n');
            for _ in 0..lvl {
                out.push_str("    ");
            }
        }
    };
    let sep = if pretty.is_some() { "," } else { ", " };
    match &v.kind {
        ValueKind::Unit => out.push_str("()"),
        ValueKind::Bool(b) => out.push_str(if *b { "true" } else { "false" }),
        ValueKind::Num(n) => out.push_str(n),
        ValueKind::Str(s) => write_str_lit(out, s),
        ValueKind::Char(c) => {
            let _ = match c {
                '\'' => write!(out, "'\\''"),
                '\\' => write!(out, "'\\\\'"),
                c => write!(out, "'{c}'"),
            };
        }
        ValueKind::Ident(i) => out.push_str(i),
        ValueKind::List(items) => {
            out.push('[');
            for (i, item) in items.iter().enumerate() {
                if i > 0 {
                    out.push_str(", ");
                }
                write_value(out, item, None, level);
            }
            out.push(']');
        }
        ValueKind::Map(entries) => {
            out.push('{');
            for (i, (k, val)) in entries.iter().enumerate() {
                if i > 0 {
                    out.push_str(sep);
                }
                nl(out, level + 1);
                write_value(out, k, pretty, level + 1);
                out.push_str(": ");
                write_value(out, val, pretty, level + 1);
            }
            if pretty.is_some() && !entries.is_empty() {
                out.push(',');
                nl(out, level);
            }
            out.push('}');
        }
        ValueKind::Struct(name, fields) => {
            if let Some(n) = name {
                out.push_str(n);
            }
            out.push('(');
            for (i, (k, val)) in fields.iter().enumerate() {
                if i > 0 {
                    out.push_str(sep);
                }
                nl(out, level + 1);
                out.push_str(k);
                out.push_str(": ");
                write_value(out, val, pretty, level + 1);
            }
            if pretty.is_some() && !fields.is_empty() {
                out.push(',');
                nl(out, level);
            }
            out.push(')');
        }
        ValueKind::Tuple(name, items) => {
            if let Some(n) = name {
                out.push_str(n);
            }
            out.push('(');
            for (i, item) in items.iter().enumerate() {
                if i > 0 {
                    out.push_str(", ");
                }
                write_value(out, item, pretty, level);
            }
            out.push(')');
        }
    }
}

/// Parses RON text into a [`Value`] tree. `file` names the source for origins; for command-line
/// text pass `None` and give `origin` for every value.
pub fn parse(
    text: &str,
    file: Option<Arc<Path>>,
    cli_origin: Option<Origin>,
) -> Result<Value, SyntaxError> {
    let mut p = Parser {
        chars: text.chars().collect(),
        pos: 0,
        line: 1,
        col: 1,
        file,
        cli_origin,
        depth: 0,
    };
    p.skip_ws()?;
    p.skip_attributes()?;
    let v = p.value()?;
    p.skip_ws()?;
    if p.pos < p.chars.len() {
        return Err(p.err(format!(
            "unexpected `{}` after the end of the value",
            p.chars[p.pos]
        )));
    }
    Ok(v)
}

struct Parser {
    chars: Vec<char>,
    pos: usize,
    line: u32,
    col: u32,
    file: Option<Arc<Path>>,
    cli_origin: Option<Origin>,
    depth: usize,
}

impl Parser {
    fn origin(&self) -> Origin {
        match (&self.file, &self.cli_origin) {
            (Some(f), _) => Origin::File {
                path: f.clone(),
                line: self.line,
                col: self.col,
            },
            (None, Some(o)) => o.clone(),
            (None, None) => Origin::Engine("<text>".into()),
        }
    }
    fn err(&self, message: String) -> SyntaxError {
        let origin = match &self.cli_origin {
            Some(Origin::Set(s)) if self.file.is_none() => {
                Origin::Set(format!("{s} (at character {})", self.col).into())
            }
            _ => self.origin(),
        };
        SyntaxError { origin, message }
    }
    fn peek(&self) -> Option<char> {
        self.chars.get(self.pos).copied()
    }
    fn peek_at(&self, k: usize) -> Option<char> {
        self.chars.get(self.pos + k).copied()
    }
    fn bump(&mut self) -> Option<char> {
        let c = self.chars.get(self.pos).copied()?;
        self.pos += 1;
        if c == '\n' {
            self.line += 1;
            self.col = 1;
        } else {
            self.col += 1;
        }
        Some(c)
    }
    fn skip_ws(&mut self) -> Result<(), SyntaxError> {
        loop {
            match self.peek() {
                Some(c) if c.is_whitespace() => {
                    self.bump();
                }
                Some('/') if self.peek_at(1) == Some('/') => {
                    while let Some(c) = self.peek() {
                        if c == '\n' {
                            break;
                        }
                        self.bump();
                    }
                }
                Some('/') if self.peek_at(1) == Some('*') => {
                    let start = self.origin();
                    self.bump();
                    self.bump();
                    let mut depth = 1;
                    while depth > 0 {
                        match self.bump() {
                            None => {
                                return Err(SyntaxError {
                                    origin: start,
                                    message: "unterminated block comment".into(),
                                })
                            }
                            Some('*') if self.peek() == Some('/') => {
                                self.bump();
                                depth -= 1;
                            }
                            Some('/') if self.peek() == Some('*') => {
                                self.bump();
                                depth += 1;
                            }
                            _ => {}
                        }
                    }
                }
                _ => return Ok(()),
            }
        }
    }
    /// Skips `#![enable(...)]` attributes.
    fn skip_attributes(&mut self) -> Result<(), SyntaxError> {
        while self.peek() == Some('#') {
            while let Some(c) = self.bump() {
                if c == ']' {
                    break;
                }
            }
            self.skip_ws()?;
        }
        Ok(())
    }
    fn expect(&mut self, c: char) -> Result<(), SyntaxError> {
        self.skip_ws()?;
        match self.peek() {
            Some(x) if x == c => {
                self.bump();
                Ok(())
            }
            Some(x) => Err(self.err(format!("expected `{c}`, found `{x}`"))),
            None => Err(self.err(format!("expected `{c}`, found the end of the text"))),
        }
    }
    fn ident(&mut self) -> String {
        let mut s = String::new();
        while let Some(c) = self.peek() {
            if c.is_alphanumeric() || c == '_' {
                s.push(c);
                self.bump();
            } else {
                break;
            }
        }
        s
    }
    fn value(&mut self) -> Result<Value, SyntaxError> {
        self.depth += 1;
        if self.depth > 128 {
            return Err(self.err("values nested too deeply".into()));
        }
        let r = self.value_inner();
        self.depth -= 1;
        r
    }
    fn value_inner(&mut self) -> Result<Value, SyntaxError> {
        self.skip_ws()?;
        let origin = self.origin();
        let c = match self.peek() {
            Some(c) => c,
            None => return Err(self.err("expected a value, found the end of the text".into())),
        };
        let kind = match c {
            '"' => ValueKind::Str(self.string()?),
            'r' if matches!(self.peek_at(1), Some('"') | Some('#')) => {
                ValueKind::Str(self.raw_string()?)
            }
            '\'' => ValueKind::Char(self.char_lit()?),
            '[' => {
                self.bump();
                let mut items = Vec::new();
                loop {
                    self.skip_ws()?;
                    if self.peek() == Some(']') {
                        self.bump();
                        break;
                    }
                    items.push(self.value()?);
                    self.skip_ws()?;
                    match self.peek() {
                        Some(',') => {
                            self.bump();
                        }
                        Some(']') => {}
                        _ => return Err(self.err("expected `,` or `]` in a list".into())),
                    }
                }
                ValueKind::List(items)
            }
            '{' => {
                self.bump();
                let mut entries = Vec::new();
                loop {
                    self.skip_ws()?;
                    if self.peek() == Some('}') {
                        self.bump();
                        break;
                    }
                    let k = self.value()?;
                    if let ValueKind::Str(name) = &k.kind {
                        let first =
                            entries
                                .iter()
                                .find_map(|(e, _): &(Value, Value)| match &e.kind {
                                    ValueKind::Str(n) if n == name => Some(e.origin.clone()),
                                    _ => None,
                                });
                        if let Some(first) = first {
                            return Err(SyntaxError {
                                origin: k.origin.clone(),
                                message: format!(
                                    "key \"{name}\" is written twice in this map (first at {first}); a second entry would silently replace the first"
                                ),
                            });
                        }
                    }
                    self.expect(':')?;
                    let v = self.value()?;
                    entries.push((k, v));
                    self.skip_ws()?;
                    match self.peek() {
                        Some(',') => {
                            self.bump();
                        }
                        Some('}') => {}
                        _ => return Err(self.err("expected `,` or `}` in a map".into())),
                    }
                }
                ValueKind::Map(entries)
            }
            '(' => self.paren_body(None)?,
            c if c.is_ascii_digit() || c == '-' || c == '+' || c == '.' => {
                ValueKind::Num(self.number()?)
            }
            c if c.is_alphabetic() || c == '_' => {
                let id = self.ident();
                let save = (self.pos, self.line, self.col);
                self.skip_ws()?;
                if self.peek() == Some('(') {
                    self.paren_body(Some(id))?
                } else {
                    (self.pos, self.line, self.col) = save;
                    match id.as_str() {
                        "true" => ValueKind::Bool(true),
                        "false" => ValueKind::Bool(false),
                        "inf" | "NaN" => ValueKind::Num(id),
                        _ => ValueKind::Ident(id),
                    }
                }
            }
            c => return Err(self.err(format!("unexpected `{c}`: expected a value"))),
        };
        Ok(Value { kind, origin })
    }
    /// After `(` (and an optional name): a struct, a tuple or unit.
    fn paren_body(&mut self, name: Option<String>) -> Result<ValueKind, SyntaxError> {
        self.expect('(')?;
        self.skip_ws()?;
        if self.peek() == Some(')') {
            self.bump();
            return Ok(match name {
                None => ValueKind::Unit,
                Some(n) => ValueKind::Struct(Some(n), Vec::new()),
            });
        }
        // A struct if the first thing is `ident :` (but not `::`).
        let save = (self.pos, self.line, self.col);
        let is_struct = {
            let first_ok = self.peek().is_some_and(|c| c.is_alphabetic() || c == '_');
            let id = if first_ok {
                self.ident()
            } else {
                String::new()
            };
            self.skip_ws()?;
            let r = !id.is_empty() && self.peek() == Some(':');
            (self.pos, self.line, self.col) = save;
            r
        };
        if is_struct {
            let mut fields: Vec<(String, Value)> = Vec::new();
            loop {
                self.skip_ws()?;
                if self.peek() == Some(')') {
                    self.bump();
                    break;
                }
                let at = self.origin();
                if !self.peek().is_some_and(|c| c.is_alphabetic() || c == '_') {
                    return Err(self.err("expected a field name".into()));
                }
                let id = self.ident();
                if fields.iter().any(|(n, _)| *n == id) {
                    return Err(SyntaxError {
                        origin: at,
                        message: format!("field `{id}` is written twice"),
                    });
                }
                self.expect(':')?;
                let v = self.value()?;
                fields.push((id, v));
                self.skip_ws()?;
                match self.peek() {
                    Some(',') => {
                        self.bump();
                    }
                    Some(')') => {}
                    _ => return Err(self.err("expected `,` or `)` after a struct field".into())),
                }
            }
            Ok(ValueKind::Struct(name, fields))
        } else {
            let mut items = Vec::new();
            loop {
                self.skip_ws()?;
                if self.peek() == Some(')') {
                    self.bump();
                    break;
                }
                items.push(self.value()?);
                self.skip_ws()?;
                match self.peek() {
                    Some(',') => {
                        self.bump();
                    }
                    Some(')') => {}
                    _ => return Err(self.err("expected `,` or `)` in a tuple".into())),
                }
            }
            Ok(ValueKind::Tuple(name, items))
        }
    }
    fn number(&mut self) -> Result<String, SyntaxError> {
        let mut s = String::new();
        if let Some(c @ ('-' | '+')) = self.peek() {
            s.push(c);
            self.bump();
            if self.peek().is_some_and(|c| c.is_alphabetic()) {
                let id = self.ident();
                if id == "inf" || id == "NaN" {
                    s.push_str(&id);
                    return Ok(s);
                }
                return Err(self.err(format!("`{s}{id}` is not a number")));
            }
        }
        while let Some(c) = self.peek() {
            let exp_sign = (c == '-' || c == '+') && s.ends_with(['e', 'E']) && !s.contains("0x");
            if c.is_ascii_alphanumeric() || c == '.' || c == '_' || exp_sign {
                s.push(c);
                self.bump();
            } else {
                break;
            }
        }
        let digits = s.trim_start_matches(['-', '+']);
        if digits.is_empty() || digits == "." {
            return Err(self.err(format!("`{s}` is not a number")));
        }
        Ok(s)
    }
    fn escape(&mut self) -> Result<char, SyntaxError> {
        match self.bump() {
            Some('n') => Ok('\n'),
            Some('t') => Ok('\t'),
            Some('r') => Ok('\r'),
            Some('0') => Ok('\0'),
            Some('\\') => Ok('\\'),
            Some('"') => Ok('"'),
            Some('\'') => Ok('\''),
            Some('u') => {
                self.expect('{')?;
                let mut hex = String::new();
                while let Some(c) = self.peek() {
                    if c == '}' {
                        break;
                    }
                    hex.push(c);
                    self.bump();
                }
                self.expect('}')?;
                u32::from_str_radix(&hex, 16)
                    .ok()
                    .and_then(char::from_u32)
                    .ok_or_else(|| self.err(format!("`\\u{{{hex}}}` is not a character")))
            }
            Some(c) => Err(self.err(format!("unknown escape `\\{c}`"))),
            None => Err(self.err("unterminated escape".into())),
        }
    }
    fn string(&mut self) -> Result<String, SyntaxError> {
        let start = self.origin();
        self.bump();
        let mut s = String::new();
        loop {
            match self.bump() {
                None => {
                    return Err(SyntaxError {
                        origin: start,
                        message: "unterminated string".into(),
                    })
                }
                Some('"') => return Ok(s),
                Some('\\') => s.push(self.escape()?),
                Some(c) => s.push(c),
            }
        }
    }
    fn raw_string(&mut self) -> Result<String, SyntaxError> {
        let start = self.origin();
        self.bump(); // r
        let mut hashes = 0;
        while self.peek() == Some('#') {
            self.bump();
            hashes += 1;
        }
        if self.bump() != Some('"') {
            return Err(self.err("expected `\"` to open a raw string".into()));
        }
        let mut s = String::new();
        loop {
            match self.bump() {
                None => {
                    return Err(SyntaxError {
                        origin: start,
                        message: "unterminated raw string".into(),
                    })
                }
                Some('"') if (0..hashes).all(|k| self.peek_at(k) == Some('#')) => {
                    for _ in 0..hashes {
                        self.bump();
                    }
                    return Ok(s);
                }
                Some(c) => s.push(c),
            }
        }
    }
    fn char_lit(&mut self) -> Result<char, SyntaxError> {
        self.bump();
        let c = match self.bump() {
            Some('\\') => self.escape()?,
            Some(c) => c,
            None => return Err(self.err("unterminated character".into())),
        };
        if self.bump() != Some('\'') {
            return Err(self.err("expected `'` to close a character".into()));
        }
        Ok(c)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(s: &str) -> Value {
        parse(s, Some(Arc::from(Path::new("t.ron"))), None).unwrap()
    }

    #[test]
    fn round_trips_and_positions() {
        let v = p("// c\n(\n  a: 1.5e-3, /* x */ b: \"s\\\"q\", c: [1, -2], d: {\"k\": Some(3)}, e: None, f: Name(x: ()),\n)");
        assert_eq!(
            v.to_ron(),
            "(a: 1.5e-3, b: \"s\\\"q\", c: [1, -2], d: {\"k\": Some(3)}, e: None, f: Name(x: ()))"
        );
        let a = v.field("a").unwrap();
        assert_eq!(
            a.origin,
            Origin::File {
                path: Arc::from(Path::new("t.ron")),
                line: 3,
                col: 6
            }
        );
        let again = p(&v.to_ron_pretty(0));
        assert_eq!(again.to_ron(), v.to_ron());
    }

    #[test]
    fn errors_have_positions() {
        let e = parse(
            "(\n  a: 1,\n  b: ]\n)",
            Some(Arc::from(Path::new("t.ron"))),
            None,
        )
        .unwrap_err();
        assert_eq!(
            e.origin,
            Origin::File {
                path: Arc::from(Path::new("t.ron")),
                line: 3,
                col: 6
            }
        );
        assert!(parse("(a: 1, a: 2)", None, None)
            .unwrap_err()
            .message
            .contains("twice"));
        assert!(parse("\"abc", None, None)
            .unwrap_err()
            .message
            .contains("unterminated"));
        assert!(parse("(a: 1) x", None, None).is_err());
    }
}
