//! `beliefbus-filter`: the filter stage as its own process. Start it by hand with
//! the pipeline's config to replace or debug it:
//! `beliefbus-filter [CONFIG] [--set KEY=VALUE ...] [--prefix PREFIX]`.

fn main() {
    std::process::exit(beliefbus::pipeline::stage_main::main(
        beliefbus::ipc::StageKind::Filter,
    ));
}
