//! Prints a `.pomdp` file's sizes, non-zeros and reward range.
fn main() {
    for path in std::env::args().skip(1) {
        let t = std::time::Instant::now();
        match beliefbus_pomdp::parse_file(std::path::Path::new(&path)) {
            Ok(p) => {
                let nnz_t: usize = p.trans.iter().map(|m| m.nnz()).sum();
                let nnz_o: usize = p.obs.iter().map(|m| m.nnz()).sum();
                println!(
                    "{path}: |S|={} |A|={} |Z|={} gamma={} nnz(T)={nnz_t} nnz(O)={nnz_o} R in {:?} ({:.3} s)",
                    p.n_states(), p.n_actions(), p.n_obs(), p.discount, p.reward_range(), t.elapsed().as_secs_f64()
                );
            }
            Err(e) => println!("error: {e}"),
        }
    }
}
