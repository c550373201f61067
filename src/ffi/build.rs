//! The body every build call shares (`sheaf_context_build_*`, their
//! joined forms, `sheaf_context_refit_bvh`): exclusive access to the
//! context (`with_mut`, or `joined` on the caller's threads), the
//! parameter struct read (NULL: the crate's defaults), the input found
//! (the borrowed geometry, or the committed two-level scene the core
//! flattens), then the core's build. Each export passes its core call.

#![forbid(unsafe_code)]

use super::context::{Handle, joined, sheaf_context, with_mut};
use super::sheaf_status;
use super::sized::{self, Versioned};
use crate::Par;
use crate::Scene;
use crate::context::Context;
use crate::error::{Error, Result};

/// The core context and the borrowed geometry's scene, borrowed apart (a
/// build writes the one while it reads the other); `NoGeometry` without a
/// geometry.
fn ctx_and_scene(h: &mut Handle) -> Result<(&mut Context<'static>, Scene<'_>)> {
    let g = h.geometry.as_ref().ok_or(Error::NoGeometry)?;
    Ok((&mut h.ctx, g.scene()?))
}

/// The body of `sheaf_context_build_*` over the borrowed geometry (and of
/// `sheaf_context_refit_bvh`): with exclusive access, `*params` read (NULL:
/// the crate's defaults) before the geometry is looked up, then
/// `core_build` on the calling thread.
pub(super) fn build<T: Versioned, R>(
    ctx: *mut sheaf_context,
    params: *const T,
    core_build: impl FnOnce(&mut Context<'static>, &Scene<'_>, &T::Core) -> Result<R>,
) -> sheaf_status
where
    T::Core: Default,
{
    with_mut(ctx, |h| {
        let p = sized::or_default(params)?;
        let (c, scene) = ctx_and_scene(h)?;
        core_build(c, &scene, &p)?;
        Ok(())
    })
}

/// [`build`] on the caller's joined threads ([`joined`]): the leader reads
/// `*params` and the geometry, `core_build` gets the session's workers.
pub(super) fn build_joined<T: Versioned, R>(
    ctx: *mut sheaf_context,
    params: *const T,
    thread_index: u32,
    thread_count: u32,
    core_build: impl FnOnce(&mut Context<'static>, &Scene<'_>, &T::Core, &dyn Par) -> Result<R>,
) -> sheaf_status
where
    T::Core: Default,
{
    joined(ctx, thread_index, thread_count, |h, par| {
        let p = sized::or_default(params)?;
        let (c, scene) = ctx_and_scene(h)?;
        core_build(c, &scene, &p, par)?;
        Ok(())
    })
}

/// The body of `sheaf_context_build_scene_*`: [`build`] over the committed
/// two-level scene, which the core flattens, instead of the geometry.
pub(super) fn build_scene<T: Versioned, R>(
    ctx: *mut sheaf_context,
    params: *const T,
    core_build: impl FnOnce(&mut Context<'static>, &T::Core) -> Result<R>,
) -> sheaf_status
where
    T::Core: Default,
{
    with_mut(ctx, |h| {
        let p = sized::or_default(params)?;
        core_build(&mut h.ctx, &p)?;
        Ok(())
    })
}

/// [`build_scene`] on the caller's joined threads ([`joined`]).
pub(super) fn build_scene_joined<T: Versioned, R>(
    ctx: *mut sheaf_context,
    params: *const T,
    thread_index: u32,
    thread_count: u32,
    core_build: impl FnOnce(&mut Context<'static>, &T::Core, &dyn Par) -> Result<R>,
) -> sheaf_status
where
    T::Core: Default,
{
    joined(ctx, thread_index, thread_count, |h, par| {
        let p = sized::or_default(params)?;
        core_build(&mut h.ctx, &p, par)?;
        Ok(())
    })
}
