//! A reader and writer for the YAML dialect of OpenCV's `FileStorage`: `%YAML:1.0` headers,
//! block mappings and sequences, flow sequences that wrap over lines, and `!!opencv-matrix`
//! tags. It is not a general YAML parser; it reads what OpenCV and its samples write.

use std::fmt::Write as _;

/// A parsed node, with the 1-based line it starts on.
#[derive(Clone, Debug, PartialEq)]
pub enum Node {
    Scalar {
        text: String,
        line: usize,
    },
    Seq {
        items: Vec<Node>,
        line: usize,
    },
    Map {
        entries: Vec<(String, Node)>,
        tag: Option<String>,
        line: usize,
    },
}

impl Node {
    pub fn line(&self) -> usize {
        match self {
            Node::Scalar { line, .. } | Node::Seq { line, .. } | Node::Map { line, .. } => *line,
        }
    }

    /// The value of `key` in a mapping.
    pub fn get(&self, key: &str) -> Option<&Node> {
        match self {
            Node::Map { entries, .. } => entries.iter().find(|(k, _)| k == key).map(|(_, v)| v),
            _ => None,
        }
    }

    fn at_line(mut self, n: usize) -> Node {
        match &mut self {
            Node::Scalar { line, .. } | Node::Seq { line, .. } | Node::Map { line, .. } => {
                *line = n
            }
        }
        self
    }

    pub fn as_scalar(&self) -> Option<&str> {
        match self {
            Node::Scalar { text, .. } => Some(text),
            _ => None,
        }
    }
}

/// A syntax error with its 1-based line.
#[derive(Debug, Clone, PartialEq)]
pub struct SyntaxError {
    pub line: usize,
    pub message: String,
}

struct Line {
    number: usize,
    indent: usize,
    text: String,
}

/// Parses a whole document; the top level must be a mapping.
pub fn parse(src: &str) -> Result<Node, SyntaxError> {
    let mut lines = Vec::new();
    for (i, raw) in src.lines().enumerate() {
        let stripped = strip_comment(raw);
        let trimmed = stripped.trim_end();
        let content = trimmed.trim_start();
        if content.is_empty() || content.starts_with('%') || content == "---" || content == "..." {
            continue;
        }
        if trimmed.contains('\t') && trimmed.len() - content.len() > 0 {
            let lead = &trimmed[..trimmed.len() - content.len()];
            if lead.contains('\t') {
                return Err(SyntaxError {
                    line: i + 1,
                    message: "tab in indentation; YAML indents with spaces".into(),
                });
            }
        }
        lines.push(Line {
            number: i + 1,
            indent: trimmed.len() - content.len(),
            text: content.to_string(),
        });
    }
    if lines.is_empty() {
        return Err(SyntaxError {
            line: 1,
            message: "empty document".into(),
        });
    }
    let mut p = Parser {
        lines,
        pos: 0,
        depth: 0,
    };
    let indent = p.lines[0].indent;
    let node = p.block(indent)?;
    if p.pos < p.lines.len() {
        let l = &p.lines[p.pos];
        return Err(SyntaxError {
            line: l.number,
            message: format!(
                "unexpected indentation before '{}'",
                crate::io::clip(&l.text, 40)
            ),
        });
    }
    match node {
        Node::Map { .. } => Ok(node),
        other => Err(SyntaxError {
            line: other.line(),
            message: "the top level of an OpenCV YAML file must be a mapping of names to values"
                .into(),
        }),
    }
}

fn strip_comment(line: &str) -> &str {
    let mut in_quote: Option<char> = None;
    let mut prev_space = true;
    for (i, c) in line.char_indices() {
        match in_quote {
            Some(q) if c == q => in_quote = None,
            Some(_) => {}
            None if c == '"' || c == '\'' => in_quote = Some(c),
            None if c == '#' && prev_space => return &line[..i],
            None => {}
        }
        prev_space = c.is_whitespace();
    }
    line
}

struct Parser {
    lines: Vec<Line>,
    pos: usize,
    /// Nesting of block collections, bounded like flow collections'.
    depth: usize,
}

/// The deepest nesting of collections read: OpenCV's files nest two or three levels; a bound
/// keeps a hostile file from exhausting the stack.
pub const MAX_DEPTH: usize = 64;

fn too_deep(line: usize) -> SyntaxError {
    SyntaxError {
        line,
        message: format!("collections nested more than {MAX_DEPTH} deep"),
    }
}

impl Parser {
    fn block(&mut self, indent: usize) -> Result<Node, SyntaxError> {
        let first = &self.lines[self.pos];
        if is_seq_item(&first.text) {
            self.block_seq(indent)
        } else {
            self.block_map(indent, None)
        }
    }

    fn block_map(&mut self, indent: usize, tag: Option<String>) -> Result<Node, SyntaxError> {
        let start = self.lines[self.pos].number;
        self.depth += 1;
        if self.depth > MAX_DEPTH {
            return Err(too_deep(start));
        }
        let node = self.block_map_entries(indent, tag, start);
        self.depth -= 1;
        node
    }

    fn block_map_entries(
        &mut self,
        indent: usize,
        tag: Option<String>,
        start: usize,
    ) -> Result<Node, SyntaxError> {
        let mut entries: Vec<(String, Node)> = Vec::new();
        let mut keys = std::collections::HashSet::new();
        while self.pos < self.lines.len() {
            let (number, line_indent) = (self.lines[self.pos].number, self.lines[self.pos].indent);
            if line_indent < indent {
                break;
            }
            if line_indent > indent {
                return Err(SyntaxError {
                    line: number,
                    message: "unexpected indentation".into(),
                });
            }
            let text = self.lines[self.pos].text.clone();
            if is_seq_item(&text) {
                break;
            }
            let (key, rest) = split_key(&text).ok_or_else(|| SyntaxError {
                line: number,
                message: format!(
                    "expected 'name: value', found '{}'",
                    crate::io::clip(&text, 40)
                ),
            })?;
            if !keys.insert(key.clone()) {
                return Err(SyntaxError {
                    line: number,
                    message: format!("duplicate key '{}'", crate::io::clip(&key, 40)),
                });
            }
            self.pos += 1;
            let value = self.value_after_key(rest, indent, number)?;
            entries.push((key, value));
        }
        Ok(Node::Map {
            entries,
            tag,
            line: start,
        })
    }

    /// The value following `key:` on line `number`, whose key sits at `indent`.
    fn value_after_key(
        &mut self,
        rest: &str,
        indent: usize,
        number: usize,
    ) -> Result<Node, SyntaxError> {
        let mut rest = rest.trim();
        let mut tag = None;
        if let Some(t) = rest.strip_prefix("!!") {
            let end = t.find(char::is_whitespace).unwrap_or(t.len());
            tag = Some(t[..end].to_string());
            rest = t[end..].trim();
        }
        if rest.is_empty() {
            // Nested block, or an empty value.
            if self.pos < self.lines.len() {
                let next = &self.lines[self.pos];
                if next.indent > indent {
                    let ni = next.indent;
                    let node = if is_seq_item(&next.text) && tag.is_none() {
                        self.block_seq(ni)?
                    } else {
                        self.block_map(ni, tag)?
                    };
                    return Ok(node.at_line(number));
                }
                if next.indent == indent && is_seq_item(&next.text) && tag.is_none() {
                    return Ok(self.block_seq(indent)?.at_line(number));
                }
            }
            return Ok(Node::Scalar {
                text: String::new(),
                line: number,
            });
        }
        if rest.starts_with('[') || rest.starts_with('{') {
            let text = self.gather_flow(rest, number)?;
            let mut f = Flow {
                s: text.as_bytes(),
                i: 0,
                line: number,
                depth: self.depth,
            };
            let node = f.value()?;
            f.skip_ws();
            if f.i != f.s.len() {
                return Err(SyntaxError {
                    line: number,
                    message: "text after the closing bracket".into(),
                });
            }
            return Ok(match (node, tag) {
                (Node::Map { entries, line, .. }, Some(t)) => Node::Map {
                    entries,
                    tag: Some(t),
                    line,
                },
                (n, _) => n,
            });
        }
        Ok(Node::Scalar {
            text: unquote(rest),
            line: number,
        })
    }

    /// Joins continuation lines until the brackets of a flow collection balance.
    fn gather_flow(&mut self, first: &str, number: usize) -> Result<String, SyntaxError> {
        let mut text = first.to_string();
        let mut balance = Balance::default();
        balance.add(first);
        loop {
            match balance.depth {
                0 => return Ok(text),
                b if b < 0 => {
                    return Err(SyntaxError {
                        line: number,
                        message: "unbalanced brackets".into(),
                    });
                }
                _ => {
                    if self.pos >= self.lines.len() {
                        return Err(SyntaxError {
                            line: number,
                            message: "unclosed '[' or '{' at end of file".into(),
                        });
                    }
                    text.push(' ');
                    text.push_str(&self.lines[self.pos].text);
                    balance.add(&self.lines[self.pos].text);
                    self.pos += 1;
                }
            }
        }
    }

    fn block_seq(&mut self, indent: usize) -> Result<Node, SyntaxError> {
        let start = self.lines[self.pos].number;
        self.depth += 1;
        if self.depth > MAX_DEPTH {
            return Err(too_deep(start));
        }
        let node = self.block_seq_items(indent, start);
        self.depth -= 1;
        node
    }

    fn block_seq_items(&mut self, indent: usize, start: usize) -> Result<Node, SyntaxError> {
        let mut items = Vec::new();
        while self.pos < self.lines.len() {
            let l = &self.lines[self.pos];
            if l.indent != indent || !is_seq_item(&l.text) {
                if l.indent > indent {
                    return Err(SyntaxError {
                        line: l.number,
                        message: "unexpected indentation in a sequence".into(),
                    });
                }
                break;
            }
            let number = l.number;
            let rest = l.text[1..].trim_start().to_string();
            let rest_indent = indent + (l.text.len() - rest.len());
            if rest.is_empty() {
                self.pos += 1;
                if self.pos < self.lines.len() && self.lines[self.pos].indent > indent {
                    let ni = self.lines[self.pos].indent;
                    items.push(self.block(ni)?);
                } else {
                    items.push(Node::Scalar {
                        text: String::new(),
                        line: number,
                    });
                }
            } else if rest.starts_with('[') || rest.starts_with('{') {
                self.pos += 1;
                let text = self.gather_flow(&rest, number)?;
                let mut f = Flow {
                    s: text.as_bytes(),
                    i: 0,
                    line: number,
                    depth: self.depth,
                };
                items.push(f.value()?);
            } else if split_key(&rest).is_some() {
                // "- key: value" starts a mapping whose keys align with "key".
                self.lines[self.pos].indent = rest_indent;
                self.lines[self.pos].text = rest;
                items.push(self.block_map(rest_indent, None)?);
            } else {
                self.pos += 1;
                items.push(Node::Scalar {
                    text: unquote(&rest),
                    line: number,
                });
            }
        }
        Ok(Node::Seq { items, line: start })
    }
}

fn is_seq_item(text: &str) -> bool {
    text == "-" || text.starts_with("- ")
}

/// Splits `key: rest` at the first unquoted `:` followed by a space or the end of the line.
fn split_key(text: &str) -> Option<(String, &str)> {
    let bytes = text.as_bytes();
    let mut in_quote: Option<u8> = None;
    for i in 0..bytes.len() {
        let c = bytes[i];
        match in_quote {
            Some(q) if c == q => in_quote = None,
            Some(_) => {}
            None if c == b'"' || c == b'\'' => in_quote = Some(c),
            None if c == b':' && (i + 1 == bytes.len() || bytes[i + 1] == b' ') => {
                let key = unquote(text[..i].trim());
                if key.is_empty() {
                    return None;
                }
                return Some((key, &text[i + 1..]));
            }
            None => {}
        }
    }
    None
}

fn unquote(s: &str) -> String {
    let s = s.trim();
    if s.len() >= 2
        && ((s.starts_with('"') && s.ends_with('"')) || (s.starts_with('\'') && s.ends_with('\'')))
    {
        s[1..s.len() - 1].to_string()
    } else {
        s.to_string()
    }
}

/// The nesting of brackets in flow text read so far, outside quotes: lines are added one at a
/// time, so joining a long collection costs its length once.
#[derive(Default)]
struct Balance {
    depth: i64,
    in_quote: Option<char>,
}

impl Balance {
    fn add(&mut self, s: &str) {
        for c in s.chars() {
            match self.in_quote {
                Some(q) if c == q => self.in_quote = None,
                Some(_) => {}
                None => match c {
                    '"' | '\'' => self.in_quote = Some(c),
                    '[' | '{' => self.depth += 1,
                    ']' | '}' => self.depth -= 1,
                    _ => {}
                },
            }
        }
    }
}

struct Flow<'a> {
    s: &'a [u8],
    i: usize,
    line: usize,
    /// Nesting so far (block collections around it included).
    depth: usize,
}

impl Flow<'_> {
    fn err(&self, message: &str) -> SyntaxError {
        SyntaxError {
            line: self.line,
            message: message.to_string(),
        }
    }

    fn skip_ws(&mut self) {
        while self.i < self.s.len() && self.s[self.i].is_ascii_whitespace() {
            self.i += 1;
        }
    }

    fn value(&mut self) -> Result<Node, SyntaxError> {
        self.depth += 1;
        if self.depth > MAX_DEPTH {
            return Err(too_deep(self.line));
        }
        let v = self.value_inner();
        self.depth -= 1;
        v
    }

    fn value_inner(&mut self) -> Result<Node, SyntaxError> {
        self.skip_ws();
        match self.s.get(self.i) {
            Some(b'[') => {
                self.i += 1;
                let mut items = Vec::new();
                loop {
                    self.skip_ws();
                    if self.s.get(self.i) == Some(&b']') {
                        self.i += 1;
                        break;
                    }
                    items.push(self.value()?);
                    self.skip_ws();
                    match self.s.get(self.i) {
                        Some(b',') => self.i += 1,
                        Some(b']') => {
                            self.i += 1;
                            break;
                        }
                        _ => return Err(self.err("expected ',' or ']' in a sequence")),
                    }
                }
                Ok(Node::Seq {
                    items,
                    line: self.line,
                })
            }
            Some(b'{') => {
                self.i += 1;
                let mut entries = Vec::new();
                loop {
                    self.skip_ws();
                    if self.s.get(self.i) == Some(&b'}') {
                        self.i += 1;
                        break;
                    }
                    let key = self.scalar(true)?;
                    self.skip_ws();
                    if self.s.get(self.i) != Some(&b':') {
                        return Err(self.err("expected ':' after a key in '{ }'"));
                    }
                    self.i += 1;
                    let v = self.value()?;
                    entries.push((key, v));
                    self.skip_ws();
                    match self.s.get(self.i) {
                        Some(b',') => self.i += 1,
                        Some(b'}') => {
                            self.i += 1;
                            break;
                        }
                        _ => return Err(self.err("expected ',' or '}' in a mapping")),
                    }
                }
                Ok(Node::Map {
                    entries,
                    tag: None,
                    line: self.line,
                })
            }
            Some(_) => Ok(Node::Scalar {
                text: self.scalar(false)?,
                line: self.line,
            }),
            None => Err(self.err("expected a value")),
        }
    }

    fn scalar(&mut self, is_key: bool) -> Result<String, SyntaxError> {
        self.skip_ws();
        if let Some(&q) = self.s.get(self.i).filter(|c| **c == b'"' || **c == b'\'') {
            let start = self.i + 1;
            let end = self.s[start..]
                .iter()
                .position(|&c| c == q)
                .ok_or_else(|| self.err("unclosed quote"))?;
            self.i = start + end + 1;
            return Ok(String::from_utf8_lossy(&self.s[start..start + end]).into_owned());
        }
        let start = self.i;
        while self.i < self.s.len() {
            let c = self.s[self.i];
            if c == b',' || c == b']' || c == b'}' || (is_key && c == b':') {
                break;
            }
            self.i += 1;
        }
        Ok(String::from_utf8_lossy(&self.s[start..self.i])
            .trim()
            .to_string())
    }
}

/// Parses an OpenCV YAML number, including `.Nan` and `.Inf`.
pub fn parse_f64(text: &str) -> Option<f64> {
    match text.trim() {
        ".Nan" | ".NaN" | ".nan" => Some(f64::NAN),
        ".Inf" | "+.Inf" | ".inf" => Some(f64::INFINITY),
        "-.Inf" | "-.inf" => Some(f64::NEG_INFINITY),
        t => t.parse().ok(),
    }
}

/// Formats a double as OpenCV does (`%.16e`, two-digit signed exponent), which round-trips.
pub fn format_f64(v: f64) -> String {
    if v.is_nan() {
        return ".Nan".into();
    }
    if v.is_infinite() {
        return if v > 0.0 {
            ".Inf".into()
        } else {
            "-.Inf".into()
        };
    }
    let s = format!("{v:.16e}");
    let (mant, exp) = s.split_once('e').expect("exponent");
    let exp: i32 = exp.parse().expect("exponent digits");
    format!("{mant}e{}{:02}", if exp < 0 { '-' } else { '+' }, exp.abs())
}

/// Writes OpenCV FileStorage YAML.
pub struct Writer {
    out: String,
}

impl Default for Writer {
    fn default() -> Self {
        Self::new()
    }
}

impl Writer {
    pub fn new() -> Self {
        Writer {
            out: "%YAML:1.0\n---\n".to_string(),
        }
    }

    pub fn scalar(&mut self, key: &str, value: impl std::fmt::Display) {
        let _ = writeln!(self.out, "{key}: {value}");
    }

    pub fn string(&mut self, key: &str, value: &str) {
        let _ = writeln!(self.out, "{key}: \"{}\"", value.replace('"', "'"));
    }

    pub fn real(&mut self, key: &str, value: f64) {
        self.scalar(key, format_f64(value));
    }

    pub fn comment(&mut self, text: &str) {
        for l in text.lines() {
            let _ = writeln!(self.out, "# {l}");
        }
    }

    /// A flow sequence of strings.
    pub fn strings(&mut self, key: &str, values: &[&str]) {
        let items: Vec<String> = values.iter().map(|v| format!("\"{v}\"")).collect();
        let _ = writeln!(self.out, "{key}: [ {} ]", items.join(", "));
    }

    /// An `!!opencv-matrix` of doubles, row-major.
    pub fn matrix(&mut self, key: &str, rows: usize, cols: usize, data: &[f64]) {
        assert_eq!(rows * cols, data.len(), "matrix data size");
        let _ = writeln!(
            self.out,
            "{key}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d"
        );
        self.out.push_str("   data: [");
        for (i, v) in data.iter().enumerate() {
            if i > 0 {
                self.out.push(',');
                if i % 3 == 0 {
                    self.out.push_str("\n      ");
                }
            }
            self.out.push(' ');
            self.out.push_str(&format_f64(*v));
        }
        self.out.push_str(" ]\n");
    }

    pub fn finish(self) -> String {
        self.out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SAMPLE: &str = "%YAML:1.0\n---\nnframes: 13\nname: \"left # not a comment\"\n\
camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 5.3e+02, 0., 3.4e+02, 0.,\n\
       5.3e+02, 2.3e+02, 0., 0., 1. ]\n# a comment\nimages:\n  - left01.jpg\n  - \"left02.jpg\"\n\
points:\n   - { x: 1, y: 2 }\n   - [ 3, 4 ]\nnested:\n   a: 1\n   b:\n      c: .Nan\n";

    #[test]
    fn parses_opencv_yaml() {
        let doc = parse(SAMPLE).unwrap();
        assert_eq!(doc.get("nframes").unwrap().as_scalar(), Some("13"));
        assert_eq!(
            doc.get("name").unwrap().as_scalar(),
            Some("left # not a comment")
        );
        let m = doc.get("camera_matrix").unwrap();
        match m {
            Node::Map { tag, line, .. } => {
                assert_eq!(tag.as_deref(), Some("opencv-matrix"));
                assert_eq!(*line, 5);
            }
            _ => panic!("not a map"),
        }
        match m.get("data").unwrap() {
            Node::Seq { items, .. } => {
                assert_eq!(items.len(), 9);
                assert_eq!(items[4].as_scalar(), Some("5.3e+02"));
            }
            _ => panic!("not a seq"),
        }
        match doc.get("images").unwrap() {
            Node::Seq { items, .. } => assert_eq!(items[1].as_scalar(), Some("left02.jpg")),
            _ => panic!(),
        }
        match doc.get("points").unwrap() {
            Node::Seq { items, .. } => {
                assert_eq!(items[0].get("y").unwrap().as_scalar(), Some("2"));
            }
            _ => panic!(),
        }
        let c = doc
            .get("nested")
            .unwrap()
            .get("b")
            .unwrap()
            .get("c")
            .unwrap();
        assert!(parse_f64(c.as_scalar().unwrap()).unwrap().is_nan());
    }

    #[test]
    fn reports_lines_of_errors() {
        let e = parse("%YAML:1.0\na: 1\nb: [ 1, 2\n").unwrap_err();
        assert_eq!(e.line, 3);
        let e = parse("a: 1\nthis is not a key\n").unwrap_err();
        assert_eq!(e.line, 2);
        let e = parse("a: 1\na: 2\n").unwrap_err();
        assert!(e.message.contains("duplicate"));
    }

    #[test]
    #[allow(clippy::excessive_precision)]
    fn numbers_round_trip_in_opencv_format() {
        for v in [535.915_733_961_631_99, -0.000_281_221, 1e-300, 0.0, -3.5e17] {
            let s = format_f64(v);
            assert_eq!(parse_f64(&s), Some(v), "{s}");
        }
        assert_eq!(format_f64(535.91573396163199), "5.3591573396163199e+02");
    }

    #[test]
    fn writer_output_parses() {
        let mut w = Writer::new();
        w.scalar("image_width", 640);
        w.matrix("m", 2, 2, &[1.0, 2.0, 3.0, 4.5]);
        w.strings("names", &["fx", "fy"]);
        let doc = parse(&w.finish()).unwrap();
        assert_eq!(doc.get("image_width").unwrap().as_scalar(), Some("640"));
        match doc.get("m").unwrap().get("data").unwrap() {
            Node::Seq { items, .. } => assert_eq!(items.len(), 4),
            _ => panic!(),
        }
    }
}
