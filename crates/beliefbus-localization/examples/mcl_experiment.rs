//! Run the `mcl` experiment without the `beliefbus` binary:
//! `cargo run --release -p beliefbus-localization --example mcl_experiment -- [runs] [key=value]...`

fn main() {
    let mut args = std::env::args().skip(1);
    let runs = args.next().and_then(|s| s.parse().ok());
    let kv: Vec<(String, String)> = args
        .filter_map(|a| {
            a.split_once('=')
                .map(|(k, v)| (k.to_string(), v.to_string()))
        })
        .collect();
    match beliefbus_localization::experiments::mcl::run(runs, 1, &kv) {
        Ok(r) => print!("{}", r.render()),
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    }
}
