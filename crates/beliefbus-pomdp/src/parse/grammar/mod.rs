//! Recursive-descent reading of the token stream (grammar in the parent
//! module's doc). Each entry starts with a keyword followed by `:`; how many
//! `:`-separated positions follow decides the entry's form (single value,
//! row or matrix), and a row or matrix takes every number up to the next
//! keyword, which must be exactly the count its form needs.

use super::lexer::{Tok, Token};
use super::tables::{ProbTable, RewardTable, Sel};
use super::ParseError;
use crate::model::{Pomdp, ROW_TOLERANCE};
use std::collections::HashMap;

mod entries;

const KEYWORDS: [&str; 9] = [
    "discount",
    "values",
    "states",
    "actions",
    "observations",
    "start",
    "T",
    "O",
    "R",
];

#[derive(Clone, Copy, PartialEq)]
enum Kind {
    State,
    Action,
    Obs,
}

impl Kind {
    fn noun(self) -> &'static str {
        match self {
            Kind::State => "state",
            Kind::Action => "action",
            Kind::Obs => "observation",
        }
    }
}

struct Space {
    names: Vec<String>,
    index: HashMap<String, u32>,
}

pub(crate) struct Parser<'a> {
    file: &'a str,
    toks: Vec<Token>,
    pos: usize,
    discount: Option<f64>,
    cost: bool,
    spaces: [Option<Space>; 3],
    start: Option<Vec<f64>>,
    start_line: usize,
    trans: Option<ProbTable>,
    obs: Option<ProbTable>,
    rewards: Option<RewardTable>,
}

type Res<T> = Result<T, ParseError>;

impl<'a> Parser<'a> {
    pub fn new(file: &'a str, toks: Vec<Token>) -> Self {
        Parser {
            file,
            toks,
            pos: 0,
            discount: None,
            cost: false,
            spaces: [None, None, None],
            start: None,
            start_line: 0,
            trans: None,
            obs: None,
            rewards: None,
        }
    }

    fn peek(&self) -> Option<&Tok> {
        self.toks.get(self.pos).map(|t| &t.tok)
    }

    fn line(&self) -> usize {
        self.toks
            .get(self.pos)
            .or(self.toks.last())
            .map_or(1, |t| t.line)
    }

    fn syntax<T>(&self, expected: &str) -> Res<T> {
        Err(ParseError::Syntax {
            file: self.file.into(),
            line: self.line(),
            expected: expected.into(),
            found: self.peek().map_or("end of file".into(), |t| t.to_string()),
        })
    }

    fn semantic<T>(&self, line: usize, message: String) -> Res<T> {
        Err(ParseError::Semantic {
            file: self.file.into(),
            line,
            message,
        })
    }

    fn colon(&mut self, after: &str) -> Res<()> {
        if self.peek() == Some(&Tok::Colon) {
            self.pos += 1;
            Ok(())
        } else {
            self.syntax(&format!("`:` after {after}"))
        }
    }

    fn is_word(&self, w: &str) -> bool {
        matches!(self.peek(), Some(Tok::Word(x)) if x == w)
    }

    fn at_keyword(&self) -> bool {
        matches!(self.peek(), Some(Tok::Word(x)) if KEYWORDS.contains(&x.as_str()))
    }

    fn space(&self, kind: Kind) -> Res<&Space> {
        let i = kind as usize;
        match &self.spaces[i] {
            Some(s) => Ok(s),
            None => self.semantic(
                self.line(),
                format!("{}s must be declared before they are used", kind.noun()),
            ),
        }
    }

    fn size(&self, kind: Kind) -> Res<usize> {
        Ok(self.space(kind)?.names.len())
    }

    pub fn parse(mut self) -> Res<Pomdp> {
        while let Some(tok) = self.peek().cloned() {
            let line = self.line();
            let Tok::Word(w) = tok else {
                return self.syntax("a preamble item or an entry (discount:, values:, states:, actions:, observations:, start:, T:, O:, R:)");
            };
            self.pos += 1;
            match w.as_str() {
                "discount" => {
                    self.colon("`discount`")?;
                    let d = self.number("the discount")?;
                    if !(0.0..=1.0).contains(&d) {
                        return self.semantic(line, format!("discount {d} is outside [0, 1]"));
                    }
                    self.discount = Some(d);
                }
                "values" => {
                    self.colon("`values`")?;
                    self.cost = if self.is_word("reward") {
                        false
                    } else if self.is_word("cost") {
                        true
                    } else {
                        return self.syntax("`reward` or `cost`");
                    };
                    self.pos += 1;
                }
                "states" => self.declare(Kind::State, line)?,
                "actions" => self.declare(Kind::Action, line)?,
                "observations" => self.declare(Kind::Obs, line)?,
                "start" => self.start_entry(line)?,
                "T" => self.t_entry(line)?,
                "O" => self.o_entry(line)?,
                "R" => self.r_entry(line)?,
                _ => {
                    self.pos -= 1;
                    return self.syntax("a preamble item or an entry (discount:, values:, states:, actions:, observations:, start:, T:, O:, R:)");
                }
            }
        }
        self.finish()
    }

    fn number(&mut self, what: &str) -> Res<f64> {
        match self.peek() {
            Some(&Tok::Num { value, .. }) => {
                self.pos += 1;
                Ok(value)
            }
            _ => self.syntax(&format!("a number ({what})")),
        }
    }

    fn prob(&mut self) -> Res<f64> {
        let line = self.line();
        let p = self.number("a probability")?;
        if !(0.0..=1.0 + ROW_TOLERANCE).contains(&p) {
            return self.semantic(line, format!("probability {p} is outside [0, 1]"));
        }
        Ok(p)
    }

    /// Every number up to the next non-number; exactly `n` of them.
    fn numbers(&mut self, n: usize, what: &str, line: usize, probs: bool) -> Res<Vec<f64>> {
        let mut out = Vec::with_capacity(n);
        while let Some(&Tok::Num { value, .. }) = self.peek() {
            if probs && !(0.0..=1.0 + ROW_TOLERANCE).contains(&value) {
                return self.semantic(
                    self.line(),
                    format!("probability {value} is outside [0, 1]"),
                );
            }
            out.push(value);
            self.pos += 1;
        }
        if out.len() != n {
            if out.is_empty() {
                return self.syntax(&format!("{n} numbers ({what})"));
            }
            return self.semantic(
                line,
                format!("expected {n} numbers ({what}), found {}", out.len()),
            );
        }
        Ok(out)
    }

    fn declare(&mut self, kind: Kind, line: usize) -> Res<()> {
        self.colon(&format!("`{}s`", kind.noun()))?;
        if self.spaces[kind as usize].is_some() {
            return self.semantic(line, format!("{}s declared twice", kind.noun()));
        }
        let names: Vec<String> = match self.peek() {
            Some(&Tok::Num { int: Some(n), .. }) if n > 0 => {
                self.pos += 1;
                (0..n).map(|i| i.to_string()).collect()
            }
            Some(Tok::Word(_)) => {
                let mut v = Vec::new();
                while let (Some(Tok::Word(w)), false) = (self.peek(), self.at_keyword()) {
                    v.push(w.clone());
                    self.pos += 1;
                }
                v
            }
            _ => {
                return self.syntax(&format!(
                    "a positive count or a list of {} names",
                    kind.noun()
                ))
            }
        };
        let mut index = HashMap::new();
        for (i, n) in names.iter().enumerate() {
            if index.insert(n.clone(), i as u32).is_some() {
                return self.semantic(line, format!("{} `{n}` named twice", kind.noun()));
            }
        }
        if names.is_empty() {
            return self.syntax(&format!("a list of {} names", kind.noun()));
        }
        self.spaces[kind as usize] = Some(Space { names, index });
        Ok(())
    }

    /// One item (name or number), or `*` → `None` when `star` is allowed.
    fn item(&mut self, kind: Kind, star: bool) -> Res<Sel> {
        let n = self.size(kind)?;
        let line = self.line();
        match self.peek().cloned() {
            Some(Tok::Star) if star => {
                self.pos += 1;
                Ok(None)
            }
            Some(Tok::Word(w)) => match self.space(kind)?.index.get(&w) {
                Some(&i) => {
                    self.pos += 1;
                    Ok(Some(i))
                }
                None => self.semantic(line, format!("unknown {} `{w}`", kind.noun())),
            },
            Some(Tok::Num { int: Some(i), .. }) => {
                if i >= n {
                    return self.semantic(
                        line,
                        format!("{} number {i} out of range (there are {n})", kind.noun()),
                    );
                }
                self.pos += 1;
                Ok(Some(i as u32))
            }
            _ => self.syntax(&format!(
                "a {} name or number{}",
                kind.noun(),
                if star { " or `*`" } else { "" }
            )),
        }
    }

    fn start_entry(&mut self, line: usize) -> Res<()> {
        let n = self.size(Kind::State)?;
        self.start_line = line;
        let include = self.is_word("include");
        if include || self.is_word("exclude") {
            self.pos += 1;
            self.colon(if include {
                "`start include`"
            } else {
                "`start exclude`"
            })?;
            let mut chosen = vec![!include; n];
            let mut any = false;
            while matches!(self.peek(), Some(Tok::Word(_)) | Some(Tok::Num { .. }))
                && !self.at_keyword()
            {
                let s = self.item(Kind::State, false)?.expect("no star allowed");
                chosen[s as usize] = include;
                any = true;
            }
            if !any {
                return self.syntax("a list of states");
            }
            let k = chosen.iter().filter(|&&c| c).count();
            if k == 0 {
                return self.semantic(line, "`start exclude:` leaves no state".into());
            }
            self.start = Some(
                chosen
                    .iter()
                    .map(|&c| if c { 1.0 / k as f64 } else { 0.0 })
                    .collect(),
            );
            return Ok(());
        }
        self.colon("`start`")?;
        let start = match self.peek().cloned() {
            Some(Tok::Word(w)) if w == "uniform" => {
                self.pos += 1;
                vec![1.0 / n as f64; n]
            }
            Some(Tok::Word(_)) => {
                let s = self.item(Kind::State, false)?.expect("no star allowed");
                one_hot(n, s)
            }
            Some(Tok::Num { int, .. }) => {
                let is_one = !matches!(
                    self.toks.get(self.pos + 1).map(|t| &t.tok),
                    Some(Tok::Num { .. })
                );
                match int {
                    Some(i) if is_one && n > 1 => {
                        let s = self.item(Kind::State, false)?.expect("no star allowed");
                        debug_assert_eq!(s as usize, i);
                        one_hot(n, s)
                    }
                    _ => self.numbers(n, "the start distribution over states", line, true)?,
                }
            }
            _ => return self.syntax("a start distribution, `uniform` or a state"),
        };
        self.start = Some(start);
        Ok(())
    }
}

fn one_hot(n: usize, s: u32) -> Vec<f64> {
    let mut v = vec![0.0; n];
    v[s as usize] = 1.0;
    v
}
