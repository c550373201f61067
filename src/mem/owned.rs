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

/// A value that borrows an `OwnedBuffer` for `'static`, stored next to it and
/// dropped before it (crate-internal: callers must never hand out
/// `&mut T` where `T` could be swapped out, see `context::OwnedContext`).
pub(crate) struct Lent<T> {
    value: core::mem::ManuallyDrop<T>,
    // Dropped after `value` (see Drop).
    _buf: OwnedBuffer,
}

impl<T> Lent<T> {
    /// Allocate `bytes` once and build the value over them.
    pub(crate) fn new<E>(
        bytes: usize,
        f: impl FnOnce(&'static mut [u8]) -> Result<T, E>,
    ) -> Result<Self, E> {
        let mut buf = OwnedBuffer::new(bytes);
        // SAFETY: lent once; the only borrow goes into `value`, which Drop
        // destroys before `_buf` frees the memory.
        let bytes = unsafe { buf.lend() };
        let value = f(bytes)?;
        Ok(Lent {
            value: core::mem::ManuallyDrop::new(value),
            _buf: buf,
        })
    }
    pub(crate) fn get(&self) -> &T {
        &self.value
    }
    pub(crate) fn get_mut(&mut self) -> &mut T {
        &mut self.value
    }
}

impl<T> Drop for Lent<T> {
    fn drop(&mut self) {
        // SAFETY: `value` is dropped exactly once, here, before `_buf`.
        unsafe { core::mem::ManuallyDrop::drop(&mut self.value) }
    }
}
