//! One heap allocation, aligned for an `Arena`, that can be lent out for
//! `'static` to a context stored next to it (the "allocating create").

use crate::mem::ARENA_ALIGN;
use bytemuck::{Pod, Zeroable};

#[repr(C, align(64))]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Block([u8; ARENA_ALIGN]);

/// A zeroed, 64-byte aligned heap buffer, made with exactly one allocation.
pub struct OwnedBuffer {
    ptr: *mut Block,
    blocks: usize,
}

// SAFETY: OwnedBuffer owns its allocation exclusively, like a Box<[Block]>.
unsafe impl Send for OwnedBuffer {}
// SAFETY: shared access only reads the pointer value, never the bytes.
unsafe impl Sync for OwnedBuffer {}

impl OwnedBuffer {
    /// Allocate `bytes` (rounded up to 64) in one allocation.
    pub fn new(bytes: usize) -> OwnedBuffer {
        let blocks = bytes.div_ceil(ARENA_ALIGN);
        // vec! of a Pod type with an exact length is one allocation, with no slack.
        let boxed: Box<[Block]> = vec![Block([0; ARENA_ALIGN]); blocks].into_boxed_slice();
        let ptr = Box::into_raw(boxed) as *mut Block;
        OwnedBuffer { ptr, blocks }
    }

    /// Lend the bytes for `'static`.
    ///
    /// # Safety
    /// The caller must drop every borrow obtained here before dropping the
    /// `OwnedBuffer`, and must call this at most once.
    pub unsafe fn lend(&mut self) -> &'static mut [u8] {
        // SAFETY: ptr/blocks come from a live Box<[Block]> we own; the caller
        // promises the borrow ends before `drop` and is the only one.
        let blocks: &'static mut [Block] =
            unsafe { core::slice::from_raw_parts_mut(self.ptr, self.blocks) };
        bytemuck::cast_slice_mut(blocks)
    }

    /// Size in bytes.
    pub fn len(&self) -> usize {
        self.blocks * ARENA_ALIGN
    }

    pub fn is_empty(&self) -> bool {
        self.blocks == 0
    }
}

impl Drop for OwnedBuffer {
    fn drop(&mut self) {
        // SAFETY: reconstructs exactly the Box<[Block]> leaked in `new`.
        drop(unsafe { Box::from_raw(core::ptr::slice_from_raw_parts_mut(self.ptr, self.blocks)) });
    }
}

/// A value that stores the buffer it was built over (`build_over`).
///
/// Implementors promise: the value keeps `buf` until it drops, drops it
/// after everything borrowing it (a last field), and never hands out a
/// borrow of the buffer longer than a borrow of itself. `Context<'static>`
/// is the one implementor: its pools are private, every accessor returns
/// data tied to `&self`, and moving or swapping it moves the buffer along.
pub(crate) trait Keeps {
    fn keep(&mut self, buf: OwnedBuffer);
}

/// Allocate `bytes` once, build a value over them, and hand it the buffer
/// to keep (`Keeps`). On error the buffer is freed with nothing borrowing
/// it.
pub(crate) fn build_over<T: Keeps, E>(
    bytes: usize,
    f: impl FnOnce(&'static mut [u8]) -> Result<T, E>,
) -> Result<T, E> {
    let mut buf = OwnedBuffer::new(bytes);
    // SAFETY: lent once; the only borrow goes into the value, which keeps
    // the buffer and drops it after that borrow (`Keeps`). When `f` fails,
    // the borrow is gone before `buf` drops at the end of this function.
    let bytes = unsafe { buf.lend() };
    let mut value = f(bytes)?;
    value.keep(buf);
    Ok(value)
}
