//! [`AVec`]: a growable buffer of `f32` or `u32` whose first element starts a 64-byte cache
//! line, for the kernels' workspaces, prepared weights and gradients.
//!
//! Why: the system allocator aligns a `Vec` to 16 bytes, so a buffer starts anywhere in its
//! first line and every 64-byte vector load or store of a kernel that walks it from the start
//! straddles two lines (two L1 accesses, and a split store when it writes). Which buffers
//! happened to start mid-line changed with the allocation order: on the bf16 LSTM epoch one
//! training shard's buffers were misaligned in places the other's were not, and that shard
//! took ≈ 3.5 % longer every batch while the other thread waited for it. With every buffer on
//! a line, measured interleaved against the same code on `Vec`s (`bowden bench train`, this
//! machine, docs/results/train-speed): the bf16 LSTM epoch 9 % shorter (median of seven pairs),
//! the f32 LSTM's 3–4 %, the TCN's 10 %. Alignment changes where the data sit, not what is
//! computed: every sum is the same, and training gives the same bytes.

use std::fmt;
use std::marker::PhantomData;
use std::ops::{Deref, DerefMut};

/// The element types an [`AVec`] may hold: 4-byte numbers for which every bit pattern is a
/// valid value and all-zero bytes are zero (sealed: `f32` and `u32`).
pub trait Plain: Copy + Default + PartialEq + fmt::Debug + sealed::Sealed + 'static {}
impl Plain for f32 {}
impl Plain for u32 {}

mod sealed {
    pub trait Sealed {}
    impl Sealed for f32 {}
    impl Sealed for u32 {}
}

/// One cache line of storage; `Vec<Line>`'s allocation is what carries the alignment.
#[derive(Clone, Copy)]
#[repr(C, align(64))]
struct Line([u8; LINE_BYTES]);

const LINE_BYTES: usize = 64;

/// A buffer of `len` elements stored in whole 64-byte lines: `Vec`'s `resize` / `clear` /
/// slice access, with the data always starting on a line. Shrinking keeps the storage (as
/// `Vec` keeps its capacity), so a workspace resized to the same length every step
/// allocates only once.
#[derive(Clone, Default)]
pub struct AVec<T: Plain> {
    lines: Vec<Line>,
    len: usize,
    _elem: PhantomData<T>,
}

impl<T: Plain> AVec<T> {
    const PER_LINE: usize = LINE_BYTES / std::mem::size_of::<T>();

    /// An empty buffer (no allocation).
    pub const fn new() -> Self {
        Self {
            lines: Vec::new(),
            len: 0,
            _elem: PhantomData,
        }
    }

    /// `n` copies of `v` (`vec![v; n]`).
    pub fn from_elem(v: T, n: usize) -> Self {
        let mut a = Self::new();
        a.resize(n, v);
        a
    }

    /// A copy of `src`.
    pub fn from_slice(src: &[T]) -> Self {
        let mut a = Self::from_elem(T::default(), src.len());
        a.copy_from_slice(src);
        a
    }

    /// `Vec::resize`: new elements (past the old length) are `v`; a shorter length keeps the
    /// storage.
    pub fn resize(&mut self, n: usize, v: T) {
        let lines = n.div_ceil(Self::PER_LINE);
        if lines > self.lines.len() {
            self.lines.resize(lines, Line([0; LINE_BYTES]));
        }
        let old = self.len;
        self.len = n;
        if n > old {
            self[old..n].fill(v);
        }
    }

    /// Length 0, storage kept.
    pub fn clear(&mut self) {
        self.len = 0;
    }
}

impl<T: Plain> Deref for AVec<T> {
    type Target = [T];
    fn deref(&self) -> &[T] {
        // SAFETY: `lines` holds at least `len` elements' bytes (`resize` keeps
        // lines.len() · PER_LINE ≥ len), its pointer is 64-byte aligned (non-null and aligned
        // even when empty), so aligned for T; every bit pattern is a valid T (`Plain`).
        unsafe { std::slice::from_raw_parts(self.lines.as_ptr() as *const T, self.len) }
    }
}

impl<T: Plain> DerefMut for AVec<T> {
    fn deref_mut(&mut self) -> &mut [T] {
        // SAFETY: as in `deref`; the borrow of `self` is exclusive.
        unsafe { std::slice::from_raw_parts_mut(self.lines.as_mut_ptr() as *mut T, self.len) }
    }
}

impl<T: Plain> fmt::Debug for AVec<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_list().entries(self.iter()).finish()
    }
}

impl<T: Plain> PartialEq for AVec<T> {
    fn eq(&self, other: &Self) -> bool {
        **self == **other
    }
}

impl<'a, T: Plain> IntoIterator for &'a AVec<T> {
    type Item = &'a T;
    type IntoIter = std::slice::Iter<'a, T>;
    fn into_iter(self) -> Self::IntoIter {
        self.iter()
    }
}

impl<'a, T: Plain> IntoIterator for &'a mut AVec<T> {
    type Item = &'a mut T;
    type IntoIter = std::slice::IterMut<'a, T>;
    fn into_iter(self) -> Self::IntoIter {
        self.iter_mut()
    }
}

impl<T: Plain> From<&[T]> for AVec<T> {
    fn from(src: &[T]) -> Self {
        Self::from_slice(src)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every buffer starts on a line, whatever its length and however it grew; `resize` and
    /// `clear` behave as `Vec`'s do.
    #[test]
    fn starts_on_a_line_and_resizes_like_vec() {
        let mut held = Vec::new();
        for n in [0usize, 1, 3, 15, 16, 17, 100, 4097] {
            // Allocations of odd sizes in between, so the allocator's 16-byte grid is hit.
            held.push(vec![0u8; 24 + n % 7]);
            let a = AVec::from_elem(1.5f32, n);
            assert_eq!(a.as_ptr() as usize % 64, 0, "length {n}");
            assert_eq!(a.len(), n);
            assert!(a.iter().all(|&v| v == 1.5));
            let b = AVec::from_elem(7u32, n);
            assert_eq!(b.as_ptr() as usize % 64, 0, "u32, length {n}");
        }
        let mut v = AVec::<f32>::new();
        let mut w = Vec::<f32>::new();
        for (n, x) in [(5, 1.0), (40, 2.0), (3, 3.0), (70, 4.0), (70, 5.0), (0, 6.0), (9, 7.0)] {
            v.resize(n, x);
            w.resize(n, x);
            assert_eq!(&v[..], &w[..], "resize to {n}");
            assert_eq!(v.as_ptr() as usize % 64, 0);
            v[..n].iter_mut().enumerate().for_each(|(i, e)| *e = i as f32);
            w[..n].iter_mut().enumerate().for_each(|(i, e)| *e = i as f32);
        }
        v.clear();
        assert!(v.is_empty());
        let c = AVec::from_slice(&[1.0f32, -0.0, f32::INFINITY]);
        assert_eq!(
            c.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
            [1.0f32, -0.0, f32::INFINITY].map(f32::to_bits)
        );
        assert_eq!(c.clone(), c);
        drop(held);
    }
}
