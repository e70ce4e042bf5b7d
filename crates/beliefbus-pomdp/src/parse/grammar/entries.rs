//! The `T:`, `O:` and `R:` entries and the final checks that assemble the
//! model (row sums, defaults, the start belief).

use super::super::lexer::Tok;
use super::super::tables::{expand, ProbTable, RewardTable, RewardValues};
use super::super::ParseError;
use super::{Kind, Parser, Res};
use crate::model::{Pomdp, ROW_TOLERANCE};

impl Parser<'_> {
    pub(super) fn tables(&mut self) -> Res<()> {
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

    pub(super) fn t_entry(&mut self, line: usize) -> Res<()> {
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

    pub(super) fn o_entry(&mut self, line: usize) -> Res<()> {
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

    pub(super) fn r_entry(&mut self, line: usize) -> Res<()> {
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

    pub(super) fn finish(mut self) -> Res<Pomdp> {
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
        .map_err(|cause| ParseError::Model { file, cause })?;
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
