//! `beliefbus-control`: the control stage as its own process. Start it by hand with
//! the pipeline's config to replace or debug it:
//! `beliefbus-control [CONFIG] [--set KEY=VALUE ...] [--prefix PREFIX]`.

fn main() {
    std::process::exit(beliefbus::pipeline::stage_main::main(
        beliefbus::ipc::StageKind::Control,
    ));
}
