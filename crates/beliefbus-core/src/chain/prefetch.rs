//! Software prefetch hints for the random-access parts of incremental
//! construction (a new state's neighbours are random slots, so their rows,
//! caches and coordinates are cache misses; hinting them all before use lets
//! the misses overlap instead of stalling one row after another).
//!
//! A hint never faults and changes no result; on targets without one it is
//! a no-op.

const LINE: usize = 64;

/// Hint the cache line holding `*x`.
#[inline(always)]
pub fn line<T>(x: &T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: prefetch is a hint; it does not dereference for the program
    // and cannot fault.
    unsafe {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        _mm_prefetch::<_MM_HINT_T0>((x as *const T).cast::<i8>());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = x;
}

/// Hint every cache line of `s`.
#[inline(always)]
pub fn range<T>(s: &[T]) {
    if s.is_empty() {
        return;
    }
    let p = s.as_ptr().cast::<u8>();
    let bytes = std::mem::size_of_val(s);
    let mut off = 0;
    while off < bytes {
        // SAFETY: `off < bytes`, inside the slice.
        line(unsafe { &*p.add(off) });
        off += LINE;
    }
    // The last line, if the slice starts mid-line and spills into it.
    // SAFETY: `bytes - 1` is the slice's last byte.
    line(unsafe { &*p.add(bytes - 1) });
}
