//! Every form of Cassandra's `.pomdp` format, each checked against the
//! tables it must produce (small inline files), and the errors for bad input
//! with the line they point at.

use beliefbus_pomdp::{parse_str, ParseError, Pomdp};

fn parse(text: &str) -> Pomdp {
    parse_str("test.pomdp", text).unwrap_or_else(|e| panic!("{e}"))
}

fn err(text: &str) -> ParseError {
    match parse_str("bad.pomdp", text) {
        Ok(_) => panic!("accepted bad input:\n{text}"),
        Err(e) => e,
    }
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() < 1e-12
}

/// Two states, two actions, two observations with every table given as
/// matrices; `extra` is appended (entries that overwrite).
fn base(preamble: &str, extra: &str) -> String {
    format!("{preamble}\nT: * identity\nO: * uniform\n{extra}\n",)
}

const PRE: &str =
    "discount: 0.9\nvalues: reward\nstates: left right\nactions: stay go\nobservations: hl hr";

#[test]
fn preamble_in_any_order_with_counts_or_names() {
    let p = parse(&base(
        "actions: 3\nobservations: a b\ndiscount: 0.5\nstates: 4\nvalues: reward",
        "",
    ));
    assert_eq!((p.n_states(), p.n_actions(), p.n_obs()), (4, 3, 2));
    assert_eq!(p.discount, 0.5);
    assert_eq!(p.action_names, ["0", "1", "2"]);
    assert_eq!(p.obs_names, ["a", "b"]);
    // no start: uniform
    assert!(p.start.iter().all(|&x| close(x, 0.25)));
    // a state and an observation may share a name (separate name spaces)
    let p = parse(&base(
        "discount: 0.9\nstates: x y\nactions: a\nobservations: x y",
        "O: a : x : x 1.0\nO: a : x : y 0\nR: a : x : * : x 5",
    ));
    assert!(close(p.reward[0][0], 5.0));
}

#[test]
fn start_forms() {
    let with = |start: &str| parse(&base(&format!("{PRE}\n{start}"), "")).start;
    let three = |start: &str| {
        parse(&format!(
            "discount: 0.9\nstates: a b c\nactions: x\nobservations: o\n{start}\nT: x identity\nO: x uniform\n"
        ))
        .start
    };
    assert_eq!(with("start: 0.25 0.75"), [0.25, 0.75]);
    assert_eq!(with("start:\n0.25\n0.75"), [0.25, 0.75]);
    assert_eq!(with("start: uniform"), [0.5, 0.5]);
    assert_eq!(with("start: right"), [0.0, 1.0]);
    assert_eq!(with("start: 1"), [0.0, 1.0]);
    assert_eq!(three("start include: a c"), [0.5, 0.0, 0.5]);
    assert_eq!(three("start exclude: a"), [0.0, 0.5, 0.5]);
    assert_eq!(three("start exclude: 0 2"), [0.0, 1.0, 0.0]);
    // within 1e-5 of 1: renormalised exactly
    let s = with("start: 0.500004 0.5");
    assert!(close(s[0] + s[1], 1.0));
}

#[test]
fn transition_forms_wildcards_and_overwrite() {
    // matrix, then a row, then single entries, in that order of overwrite
    let p = parse(&base(
        PRE,
        "T: go\n0.2 0.8\n0.6 0.4\nT: go : right\n0.3 0.7\nT: go : left : left 0.1\nT: go : left : right 0.9",
    ));
    assert_eq!(p.trans[1].get(0, 0), 0.1);
    assert_eq!(p.trans[1].get(0, 1), 0.9);
    assert_eq!(p.trans[1].get(1, 0), 0.3);
    assert_eq!(p.trans[1].get(1, 1), 0.7);
    assert_eq!(p.trans[0].get(0, 0), 1.0); // identity untouched
                                           // uniform matrix and row, wildcards in every position
    let p = parse(&base(PRE, "T: stay uniform\nT: go : * uniform"));
    assert_eq!(p.trans[0].get(1, 0), 0.5);
    assert_eq!(p.trans[1].get(0, 1), 0.5);
    let p = parse(&base(PRE, "T: * : * : * 0\nT: * : * : right 1"));
    for a in 0..2 {
        for s in 0..2 {
            assert_eq!((p.trans[a].get(s, 0), p.trans[a].get(s, 1)), (0.0, 1.0));
        }
    }
    // `reset` row = the start distribution; optional `:` before the value
    let p = parse(&base(
        &format!("{PRE}\nstart: 0.3 0.7"),
        "T: go : left reset\nT: stay : right : left : 1\nT: stay : right : right : 0",
    ));
    assert_eq!((p.trans[1].get(0, 0), p.trans[1].get(0, 1)), (0.3, 0.7));
    assert_eq!(p.trans[0].get(1, 0), 1.0);
}

#[test]
fn observation_forms() {
    let p = parse(&base(
        PRE,
        "O: stay\n0.85 0.15\n0.15 0.85\nO: go : right\n0.4 0.6\nO: go : left : hl 1\nO: go : left : hr 0",
    ));
    assert_eq!(p.obs[0].get(0, 0), 0.85);
    assert_eq!(p.obs[0].get(1, 1), 0.85);
    assert_eq!((p.obs[1].get(0, 0), p.obs[1].get(0, 1)), (1.0, 0.0));
    assert_eq!((p.obs[1].get(1, 0), p.obs[1].get(1, 1)), (0.4, 0.6));
    let p = parse(&base(
        PRE,
        "O: * : * : * 0\nO: * : * : hr 1\nO: go : * uniform",
    ));
    assert_eq!(p.obs[0].get(0, 1), 1.0);
    assert_eq!(p.obs[1].get(1, 0), 0.5);
}

#[test]
fn reward_forms_reduce_to_expected_immediate_reward() {
    // T(go): left → (0.2 left, 0.8 right), right → right.
    // O(go): in left hl w.p. 0.9, in right hl w.p. 0.3.
    let model = |rewards: &str, values: &str| {
        parse(&format!(
            "discount: 0.9\nvalues: {values}\nstates: left right\nactions: stay go\nobservations: hl hr\n\
             T: stay identity\nT: go\n0.2 0.8\n0 1\nO: stay uniform\nO: go\n0.9 0.1\n0.3 0.7\n{rewards}\n"
        ))
    };
    let (t, o) = ([[0.2, 0.8], [0.0, 1.0]], [[0.9, 0.1], [0.3, 0.7]]);
    // r(go, s, s', o) given as a full table: check the reduction exactly.
    let r = |s: usize, s2: usize, ob: usize| (10 * s + 3 * s2 + ob) as f64 - 4.0;
    let expect = |s: usize| -> f64 {
        (0..2)
            .flat_map(|s2| (0..2).map(move |ob| (s2, ob)))
            .map(|(s2, ob)| t[s][s2] * o[s2][ob] * r(s, s2, ob))
            .sum()
    };
    let single: String = (0..2)
        .flat_map(|s| (0..2).flat_map(move |s2| (0..2).map(move |ob| (s, s2, ob))))
        .map(|(s, s2, ob)| format!("R: go : {s} : {s2} : {ob} {}\n", r(s, s2, ob)))
        .collect();
    let rows: String = (0..2)
        .flat_map(|s| (0..2).map(move |s2| (s, s2)))
        .map(|(s, s2)| format!("R: go : {s} : {s2}\n{} {}\n", r(s, s2, 0), r(s, s2, 1)))
        .collect();
    let matrix: String = (0..2)
        .map(|s| {
            format!(
                "R: go : {s}\n{} {}\n{} {}\n",
                r(s, 0, 0),
                r(s, 0, 1),
                r(s, 1, 0),
                r(s, 1, 1)
            )
        })
        .collect();
    for text in [&single, &rows, &matrix] {
        let p = model(text, "reward");
        for s in 0..2 {
            assert!(
                close(p.reward[1][s], expect(s)),
                "{text}: {:?}",
                p.reward[1]
            );
            assert_eq!(p.reward[0][s], 0.0);
        }
        // `values: cost` negates
        let c = model(text, "cost");
        assert!(close(c.reward[1][0], -expect(0)));
    }
    // wildcards, end-state and observation keys, later entries overwrite
    let p = model(
        "R: * : * : * : * 1\nR: go : * : right : * 5\nR: go : left : * : hr -10\nR: stay : right : * : * 2",
        "reward",
    );
    // go from left: s'=left: hl→1 (0.9), hr→-10 (0.1); s'=right: hl→5, hr→-10
    let go_left = 0.2 * (0.9 * 1.0 + 0.1 * -10.0) + 0.8 * (0.3 * 5.0 + 0.7 * -10.0);
    assert!(close(p.reward[1][0], go_left), "{}", p.reward[1][0]);
    assert!(close(p.reward[1][1], 5.0));
    assert_eq!((p.reward[0][0], p.reward[0][1]), (1.0, 2.0));
}

#[test]
fn layout_comments_tabs_crlf_and_numbers_on_next_lines() {
    let text = "# header comment\r\ndiscount:\t0.9 # trailing\r\nvalues: reward\r\nstates: left right\r\n\
                actions: stay go\r\nobservations: hl hr\r\nstart:\r\n0.5\r\n0.5\r\n\
                T:stay identity\r\nT: go : left : right\r\n 1.0 # on its own line\r\nT: go : right\t:\tright 1\r\n\
                O: * uniform\r\nR: go : left : * : *\r\n\t-3\r\n";
    let p = parse(text);
    assert_eq!(p.trans[1].get(0, 1), 1.0);
    assert_eq!(p.reward[1][0], -3.0);
    assert_eq!(p.start, [0.5, 0.5]);
}

#[test]
fn nearly_stochastic_rows_are_normalised_bad_rows_are_named() {
    let p = parse(&base(PRE, "T: go\n0.333333 0.666666\n0.5 0.5"));
    assert!(close(p.trans[1].get(0, 0) + p.trans[1].get(0, 1), 1.0));
    let e = err(&base(PRE, "T: go\n0.3 0.6\n0.5 0.5"));
    let msg = e.to_string();
    assert_eq!(e.line(), Some(8), "{msg}");
    assert!(
        msg.contains("T row for action `go`, start state `left`"),
        "{msg}"
    );
    assert!(msg.contains("sums to 0.9"), "{msg}");
    let e = err(&base(PRE, "O: stay : right : hl 0.9"));
    assert!(
        e.to_string()
            .contains("O row for action `stay`, end state `right`"),
        "{e}"
    );
    assert_eq!(e.line(), Some(8));
}

#[test]
fn errors_name_file_line_and_what_was_expected() {
    let cases: [(&str, usize, &str); 9] = [
        (
            &base(PRE, "T: go : middle : left 1"),
            8,
            "unknown state `middle`",
        ),
        (&base(PRE, "T: jump identity"), 8, "unknown action `jump`"),
        (
            &base(PRE, "O: go : left : hx 1"),
            8,
            "unknown observation `hx`",
        ),
        (
            &base(PRE, "T: go : 2 : left 1"),
            8,
            "state number 2 out of range",
        ),
        (&base(PRE, "T: go\n0.5 0.5\n0.5"), 8, "expected 4 numbers"),
        (
            &base(PRE, "T: go : left : right"),
            8,
            "expected a number (a probability)",
        ),
        (&base(PRE, "T: go : left : right 1.5"), 8, "outside [0, 1]"),
        (
            &base(PRE, "R go : * : * : * 1"),
            8,
            "expected `:` after `R`",
        ),
        (&base(PRE, "Z: go"), 8, "a preamble item or an entry"),
    ];
    for (text, line, says) in cases {
        let e = err(text);
        let msg = e.to_string();
        assert!(msg.starts_with("bad.pomdp:"), "{msg}");
        assert!(msg.contains(says), "expected `{says}` in: {msg}");
        if !says.contains("preamble") {
            assert_eq!(e.line(), Some(line), "{msg}");
        }
    }
    let e = err(&base(&PRE.replace("discount: 0.9\n", ""), ""));
    assert!(e.to_string().contains("missing `discount:`"), "{e}");
    let e = err("discount: 0.9\nstates: 2\nactions: 1\nobservations: 1\nT: 0 identity\n");
    assert!(
        e.to_string()
            .contains("O row for action `0`, end state `0` (every row must be given)"),
        "{e}"
    );
    let e = err("discount: 0.9\nstates: a b\nactions: x\nobservations: o\nstart: 0.5 0.4\nT: x identity\nO: x uniform\n");
    assert_eq!(e.line(), Some(5), "{e}");
    assert!(e.to_string().contains("start distribution"), "{e}");
    let e = err("discount: 0.9\nstates: 2\nactions: 1\nobservations: 1\nT: 0 identity 3$\n");
    assert!(
        e.to_string().contains("bad.pomdp:5: expected a name"),
        "{e}"
    );
}
