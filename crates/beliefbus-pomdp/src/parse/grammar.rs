//! Recursive-descent reading of the token stream (grammar in the parent
//! module's doc). Each entry starts with a keyword followed by `:`; how many
//! `:`-separated positions follow decides the entry's form (single value,
//! row or matrix), and a row or matrix takes every number up to the next
//! keyword, which must be exactly the count its form needs.

use super::lexer::{Tok, Token};
use super::tables::{expand, ProbTable, RewardTable, RewardValues, Sel};
use super::ParseError;
use crate::model::{Pomdp, ROW_TOLERANCE};
use std::collections::HashMap;

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

    fn tables(&mut self) -> Res<()> {
        if self.trans.is_none() {
            let (ns, na, no) = (
                self.size(Kind::State)?,
                self.size(Kind::Action)?,
                self.size(Kind::Obs)?,
            );
            self.trans = Some(ProbTable::new(na, ns, ns));
            self.obs = Some(ProbTable::new(na, ns, no));
            self.rewards = Some(RewardTable::new(no));
        }
        Ok(())
    }

    /// `uniform`, `reset` (T only) or exactly `n` probabilities.
    fn prob_row(&mut self, n: usize, what: &str, line: usize, reset: bool) -> Res<Vec<f64>> {
        if self.is_word("uniform") {
            self.pos += 1;
            return Ok(vec![1.0 / n as f64; n]);
        }
        if reset && self.is_word("reset") {
            self.pos += 1;
            let ns = self.size(Kind::State)?;
            return Ok(self
                .start
                .clone()
                .unwrap_or_else(|| vec![1.0 / ns as f64; ns]));
        }
        self.numbers(n, what, line, true)
    }

    fn t_entry(&mut self, line: usize) -> Res<()> {
        self.colon("`T`")?;
        self.tables()?;
        let (ns, na) = (self.size(Kind::State)?, self.size(Kind::Action)?);
        let a = self.item(Kind::Action, true)?;
        if self.peek() == Some(&Tok::Colon) {
            self.pos += 1;
            let s = self.item(Kind::State, true)?;
            if self.peek() == Some(&Tok::Colon) {
                self.pos += 1;
                let s2 = self.item(Kind::State, true)?;
                if self.peek() == Some(&Tok::Colon) {
                    self.pos += 1;
                }
                let p = self.prob()?;
                let t = self.trans.as_mut().expect("tables made");
                for a in expand(a, na) {
                    for s in expand(s, ns) {
                        for s2 in expand(s2, ns) {
                            t.set_cell(a, s, s2, p, line);
                        }
                    }
                }
            } else {
                let row = self.prob_row(ns, "a row of T over end states", line, true)?;
                let t = self.trans.as_mut().expect("tables made");
                for a in expand(a, na) {
                    for s in expand(s, ns) {
                        t.set_row(a, s, &row, line);
                    }
                }
            }
            return Ok(());
        }
        let t_rows = |t: &mut ProbTable, row: &dyn Fn(usize) -> Vec<(u32, f64)>| {
            for a in expand(a, na) {
                for s in 0..ns {
                    t.set_sparse_row(a, s as u32, row(s), line);
                }
            }
        };
        if self.is_word("identity") {
            self.pos += 1;
            t_rows(self.trans.as_mut().expect("tables made"), &|s| {
                vec![(s as u32, 1.0)]
            });
        } else if self.is_word("uniform") {
            self.pos += 1;
            let u = 1.0 / ns as f64;
            t_rows(self.trans.as_mut().expect("tables made"), &|_| {
                (0..ns as u32).map(|j| (j, u)).collect()
            });
        } else {
            let m = self.numbers(ns * ns, "a |S|x|S| matrix of T", line, true)?;
            let t = self.trans.as_mut().expect("tables made");
            for a in expand(a, na) {
                for s in 0..ns {
                    t.set_row(a, s as u32, &m[s * ns..(s + 1) * ns], line);
                }
            }
        }
        Ok(())
    }

    fn o_entry(&mut self, line: usize) -> Res<()> {
        self.colon("`O`")?;
        self.tables()?;
        let (ns, na, no) = (
            self.size(Kind::State)?,
            self.size(Kind::Action)?,
            self.size(Kind::Obs)?,
        );
        let a = self.item(Kind::Action, true)?;
        if self.peek() == Some(&Tok::Colon) {
            self.pos += 1;
            let s2 = self.item(Kind::State, true)?;
            if self.peek() == Some(&Tok::Colon) {
                self.pos += 1;
                let o = self.item(Kind::Obs, true)?;
                if self.peek() == Some(&Tok::Colon) {
                    self.pos += 1;
                }
                let p = self.prob()?;
                let t = self.obs.as_mut().expect("tables made");
                for a in expand(a, na) {
                    for s2 in expand(s2, ns) {
                        for o in expand(o, no) {
                            t.set_cell(a, s2, o, p, line);
                        }
                    }
                }
            } else {
                let row = self.prob_row(no, "a row of O over observations", line, false)?;
                let t = self.obs.as_mut().expect("tables made");
                for a in expand(a, na) {
                    for s2 in expand(s2, ns) {
                        t.set_row(a, s2, &row, line);
                    }
                }
            }
            return Ok(());
        }
        let m = if self.is_word("uniform") {
            self.pos += 1;
            vec![1.0 / no as f64; ns * no]
        } else {
            self.numbers(ns * no, "a |S|x|Z| matrix of O", line, true)?
        };
        let t = self.obs.as_mut().expect("tables made");
        for a in expand(a, na) {
            for s in 0..ns {
                t.set_row(a, s as u32, &m[s * no..(s + 1) * no], line);
            }
        }
        Ok(())
    }

    fn r_entry(&mut self, line: usize) -> Res<()> {
        self.colon("`R`")?;
        self.tables()?;
        let (ns, no) = (self.size(Kind::State)?, self.size(Kind::Obs)?);
        let a = self.item(Kind::Action, true)?;
        self.colon("the action of an R entry")?;
        let s = self.item(Kind::State, true)?;
        let values = if self.peek() == Some(&Tok::Colon) {
            self.pos += 1;
            let end = self.item(Kind::State, true)?;
            if self.peek() == Some(&Tok::Colon) {
                self.pos += 1;
                let obs = self.item(Kind::Obs, true)?;
                if self.peek() == Some(&Tok::Colon) {
                    self.pos += 1;
                }
                let value = self.number("a reward")?;
                RewardValues::Cell { end, obs, value }
            } else {
                let values = self.numbers(no, "a row of rewards over observations", line, false)?;
                RewardValues::Row { end, values }
            }
        } else {
            let values = self.numbers(ns * no, "a |S|x|Z| matrix of rewards", line, false)?;
            RewardValues::Matrix { values }
        };
        self.rewards
            .as_mut()
            .expect("tables made")
            .push(a, s, values);
        Ok(())
    }

    fn finish(mut self) -> Res<Pomdp> {
        let missing = |what: &str| ParseError::Missing {
            file: self.file.into(),
            what: what.into(),
        };
        let discount = self.discount.ok_or_else(|| missing("`discount:`"))?;
        for (k, name) in [
            (Kind::State, "`states:`"),
            (Kind::Action, "`actions:`"),
            (Kind::Obs, "`observations:`"),
        ] {
            if self.spaces[k as usize].is_none() {
                return Err(missing(name));
            }
        }
        self.tables()?;
        let (ns, na) = (self.size(Kind::State)?, self.size(Kind::Action)?);
        let mut start = self
            .start
            .take()
            .unwrap_or_else(|| vec![1.0 / ns as f64; ns]);
        let sum: f64 = start.iter().sum();
        self.check_sum(sum, "the start distribution".into(), self.start_line)?;
        start.iter_mut().for_each(|p| *p /= sum);
        let mut trans = self.trans.take().expect("tables made");
        let mut obs = self.obs.take().expect("tables made");
        for (table, is_t) in [(&mut trans, true), (&mut obs, false)] {
            for a in 0..na {
                for s in 0..ns {
                    let sum: f64 = table.row(a, s).iter().map(|&(_, p)| p).sum();
                    let what = format!(
                        "{} row for action `{}`, {} state `{}`",
                        if is_t { "T" } else { "O" },
                        self.space(Kind::Action)?.names[a],
                        if is_t { "start" } else { "end" },
                        self.space(Kind::State)?.names[s],
                    );
                    if table.line[a * ns + s] == 0 {
                        return Err(missing(&format!("{what} (every row must be given)")));
                    }
                    self.check_sum(sum, what, table.line[a * ns + s])?;
                    table.scale_row(a, s, 1.0 / sum);
                }
            }
        }
        let mut reward = self
            .rewards
            .take()
            .expect("tables made")
            .reduce(&trans, &obs, na);
        if self.cost {
            reward.iter_mut().flatten().for_each(|r| *r = -*r);
        }
        let file = self.file.to_string();
        let mut p = Pomdp::new(
            discount,
            start,
            trans.into_matrices(na),
            obs.into_matrices(na),
            reward,
        )
        .map_err(|source| ParseError::Model { file, source })?;
        let [s, a, o] = self.spaces.map(|sp| sp.expect("checked").names);
        (p.state_names, p.action_names, p.obs_names) = (s, a, o);
        Ok(p)
    }

    fn check_sum(&self, sum: f64, what: String, line: usize) -> Res<()> {
        if (sum - 1.0).abs() > ROW_TOLERANCE {
            return Err(ParseError::RowSum {
                file: self.file.into(),
                line,
                what,
                sum,
                tol: ROW_TOLERANCE,
            });
        }
        Ok(())
    }
}

fn one_hot(n: usize, s: u32) -> Vec<f64> {
    let mut v = vec![0.0; n];
    v[s as usize] = 1.0;
    v
}
