//! `beliefbus`: the user-facing command with the built-in scenarios (see
//! [`beliefbus::cli`]; a user's own binary calls `cli::main_with` with its
//! registry).

fn main() {
    std::process::exit(beliefbus::cli::main_with(
        beliefbus::scenario::Registry::builtin(),
    ));
}
