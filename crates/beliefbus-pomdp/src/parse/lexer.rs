//! Tokens of Cassandra's `.pomdp` format: `#` comments to the end of the
//! line; whitespace (spaces, tabs, CR, LF) separates tokens; `:` and `*` are
//! tokens of their own even when glued to a word (`T:listen`); a word that
//! starts with a letter is a name or keyword, anything else must be a number.
//! Line breaks carry no meaning (an entry's numbers may follow on the next
//! lines), so tokens only remember their line for error messages.

use super::ParseError;

#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Tok {
    Colon,
    Star,
    /// A name or keyword, as written.
    Word(String),
    /// A number; `int` when written without `.`/exponent and non-negative
    /// (an index may be written that way).
    Num {
        value: f64,
        int: Option<usize>,
    },
}

#[derive(Clone, Debug)]
pub(crate) struct Token {
    pub tok: Tok,
    pub line: usize,
}

pub(crate) fn lex(file: &str, text: &str) -> Result<Vec<Token>, ParseError> {
    let mut out = Vec::new();
    for (i, raw) in text.split('\n').enumerate() {
        let line = i + 1;
        let content = raw.split('#').next().unwrap_or("");
        let mut word = String::new();
        let flush = |word: &mut String, out: &mut Vec<Token>| -> Result<(), ParseError> {
            if word.is_empty() {
                return Ok(());
            }
            let w = std::mem::take(word);
            let tok = classify(&w).ok_or_else(|| ParseError::Syntax {
                file: file.into(),
                line,
                expected: "a name (starting with a letter) or a number".into(),
                found: format!("`{w}`"),
            })?;
            out.push(Token { tok, line });
            Ok(())
        };
        for c in content.chars() {
            match c {
                ':' | '*' => {
                    flush(&mut word, &mut out)?;
                    out.push(Token {
                        tok: if c == ':' { Tok::Colon } else { Tok::Star },
                        line,
                    });
                }
                c if c.is_whitespace() => flush(&mut word, &mut out)?,
                c => word.push(c),
            }
        }
        flush(&mut word, &mut out)?;
    }
    Ok(out)
}

fn classify(w: &str) -> Option<Tok> {
    let first = w.chars().next()?;
    if first.is_ascii_alphabetic() {
        let ok = w
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-' || c == '.');
        return ok.then(|| Tok::Word(w.to_string()));
    }
    let value: f64 = w.parse().ok()?;
    if !value.is_finite() {
        return None;
    }
    let int = if w.bytes().all(|b| b.is_ascii_digit()) {
        w.parse().ok()
    } else {
        None
    };
    Some(Tok::Num { value, int })
}

impl std::fmt::Display for Tok {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Tok::Colon => write!(f, "`:`"),
            Tok::Star => write!(f, "`*`"),
            Tok::Word(w) => write!(f, "`{w}`"),
            Tok::Num { value, .. } => write!(f, "number `{value}`"),
        }
    }
}
