//! The parser of the Python literal that a `.npy` header holds: a dict of strings,
//! integers, booleans, `None`, tuples and lists, nested to a bounded depth.

/// Deepest nesting of tuples/lists/dicts accepted in a `.npy` header, so that a
/// hostile header cannot exhaust the stack.
const MAX_HEADER_DEPTH: usize = 16;

/// A Python literal as found in an npy header.
#[derive(Debug, Clone, PartialEq)]
pub(super) enum Literal {
    /// A string.
    Str(String),
    /// An integer.
    Int(i128),
    /// `True` or `False`.
    Bool(bool),
    /// `None`.
    None,
    /// A tuple.
    Tuple(Vec<Literal>),
    /// A list.
    List(Vec<Literal>),
    /// A dict with string keys, in source order.
    Dict(Vec<(String, Literal)>),
}

/// Parses a whole npy header (a Python literal followed only by whitespace).
pub(super) fn parse_literal(text: &str) -> Result<Literal, String> {
    let mut p = LiteralParser {
        s: text.as_bytes(),
        pos: 0,
    };
    let value = p.value(0)?;
    p.skip_ws();
    if p.pos != p.s.len() {
        return Err(format!(
            "bad npy header: unexpected text at offset {}",
            p.pos
        ));
    }
    Ok(value)
}

/// Recursive-descent parser over the header bytes.
struct LiteralParser<'a> {
    /// The header text.
    s: &'a [u8],
    /// Current offset.
    pos: usize,
}

impl LiteralParser<'_> {
    /// Error for malformed input at the current offset.
    fn err(&self, what: &str) -> String {
        format!("bad npy header: {what} at offset {}", self.pos)
    }

    /// Skips whitespace.
    fn skip_ws(&mut self) {
        while self
            .s
            .get(self.pos)
            .is_some_and(|b| b.is_ascii_whitespace())
        {
            self.pos += 1;
        }
    }

    /// Next non-whitespace byte, not consumed.
    fn peek(&mut self) -> Option<u8> {
        self.skip_ws();
        self.s.get(self.pos).copied()
    }

    /// Parses one value, `depth` levels deep: a dict, tuple or list, string, integer or name.
    fn value(&mut self, depth: usize) -> Result<Literal, String> {
        if depth > MAX_HEADER_DEPTH {
            return Err(self.err("nesting too deep"));
        }
        match self.peek() {
            None => Err(self.err("unexpected end")),
            Some(b'{') => self.dict(depth),
            Some(open @ (b'(' | b'[')) => self.sequence(open, depth),
            Some(q @ (b'\'' | b'"')) => self.string(q),
            Some(c) if c == b'-' || c == b'+' || c.is_ascii_digit() => self.int(),
            Some(c) if c.is_ascii_alphabetic() => self.name(),
            Some(_) => Err(self.err("unexpected character")),
        }
    }

    /// A dict `{'key': value, ...}` (string keys), at its `{`.
    fn dict(&mut self, depth: usize) -> Result<Literal, String> {
        self.pos += 1;
        let mut items = Vec::new();
        loop {
            if self.peek() == Some(b'}') {
                self.pos += 1;
                return Ok(Literal::Dict(items));
            }
            let key = match self.value(depth + 1)? {
                Literal::Str(k) => k,
                _ => return Err(self.err("dict key is not a string")),
            };
            if self.peek() != Some(b':') {
                return Err(self.err("expected ':'"));
            }
            self.pos += 1;
            let value = self.value(depth + 1)?;
            items.push((key, value));
            match self.peek() {
                Some(b',') => self.pos += 1,
                Some(b'}') => {}
                _ => return Err(self.err("expected ',' or '}'")),
            }
        }
    }

    /// A tuple `(...)` or list `[...]` opened by `open`, at it.
    fn sequence(&mut self, open: u8, depth: usize) -> Result<Literal, String> {
        self.pos += 1;
        let close = if open == b'(' { b')' } else { b']' };
        let mut items = Vec::new();
        let mut trailing_comma = false;
        loop {
            if self.peek() == Some(close) {
                self.pos += 1;
                break;
            }
            items.push(self.value(depth + 1)?);
            trailing_comma = false;
            match self.peek() {
                Some(b',') => {
                    self.pos += 1;
                    trailing_comma = true;
                }
                Some(c) if c == close => {}
                _ => return Err(self.err("expected ',' or closing bracket")),
            }
        }
        if open == b'(' {
            // `(x)` is just `x` in Python; `(x,)` is a tuple.
            if items.len() == 1 && !trailing_comma {
                return Ok(items.pop().unwrap_or(Literal::None));
            }
            Ok(Literal::Tuple(items))
        } else {
            Ok(Literal::List(items))
        }
    }

    /// A string quoted by `q` (backslash escapes the next byte), at its opening quote.
    fn string(&mut self, q: u8) -> Result<Literal, String> {
        self.pos += 1;
        let mut out = Vec::new();
        loop {
            match self.s.get(self.pos).copied() {
                None => return Err(self.err("unterminated string")),
                Some(b'\\') => {
                    let next = self
                        .s
                        .get(self.pos + 1)
                        .copied()
                        .ok_or_else(|| self.err("unterminated string"))?;
                    out.push(next);
                    self.pos += 2;
                }
                Some(c) if c == q => {
                    self.pos += 1;
                    break;
                }
                Some(c) => {
                    out.push(c);
                    self.pos += 1;
                }
            }
        }
        String::from_utf8(out)
            .map(Literal::Str)
            .map_err(|_| self.err("string is not valid UTF-8"))
    }

    /// A signed decimal integer (an old `L` suffix skipped).
    fn int(&mut self) -> Result<Literal, String> {
        let start = self.pos;
        self.pos += 1;
        while self.s.get(self.pos).is_some_and(u8::is_ascii_digit) {
            self.pos += 1;
        }
        let digits =
            std::str::from_utf8(&self.s[start..self.pos]).map_err(|_| self.err("bad integer"))?;
        let value: i128 = digits.parse().map_err(|_| self.err("bad integer"))?;
        // Python 2 long suffix, as in very old files: `(3L,)`.
        if matches!(self.s.get(self.pos), Some(b'L' | b'l')) {
            self.pos += 1;
        }
        Ok(Literal::Int(value))
    }

    /// `True`, `False` or `None`.
    fn name(&mut self) -> Result<Literal, String> {
        let start = self.pos;
        while self.s.get(self.pos).is_some_and(u8::is_ascii_alphanumeric) {
            self.pos += 1;
        }
        match &self.s[start..self.pos] {
            b"True" => Ok(Literal::Bool(true)),
            b"False" => Ok(Literal::Bool(false)),
            b"None" => Ok(Literal::None),
            _ => {
                self.pos = start;
                Err(self.err("unknown name"))
            }
        }
    }
}
