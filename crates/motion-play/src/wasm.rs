//! The functions the page calls (C ABI; numbers and byte buffers only, no
//! JavaScript glue): the page copies the bundle into [`play_alloc`]'s
//! buffer, calls [`play_new`], then [`play_step`] once per frame and reads
//! the frame at [`play_frame`]. A call that fails returns 0 (or a negative
//! count) and leaves its message at [`play_error`].

use crate::{Frame, Player};
use mocap_ingest::skeleton::NUM_JOINTS;
use motion_steer::Keys;
use std::cell::RefCell;

/// Values of a frame at [`play_frame`]: the joints' xyz, then the root's
/// position (x, z, metres) and facing (x, z), the asked heading (x, z) and
/// speed, and the category asked.
pub const FRAME_VALUES: usize = 3 * NUM_JOINTS + 8;

thread_local! {
    static PLAYER: RefCell<Option<Player>> = const { RefCell::new(None) };
    static FRAME: RefCell<[f32; FRAME_VALUES]> = const { RefCell::new([0.0; FRAME_VALUES]) };
    static TEXT: RefCell<String> = const { RefCell::new(String::new()) };
}

fn fail(e: impl std::fmt::Display) -> i32 {
    TEXT.with(|m| *m.borrow_mut() = e.to_string());
    0
}

/// A buffer of `len` bytes for the page to fill (leaked: the page makes one).
#[unsafe(no_mangle)]
pub extern "C" fn play_alloc(len: usize) -> *mut u8 {
    Box::leak(vec![0u8; len].into_boxed_slice()).as_mut_ptr()
}

/// Starts the player of the bundle at `ptr..ptr + len` (from
/// [`play_alloc`]) with `seed`: the number of categories, or 0.
///
/// # Safety
/// `ptr` and `len` are a buffer [`play_alloc`] returned.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn play_new(ptr: *const u8, len: usize, seed: f64) -> i32 {
    // SAFETY: the page passes the buffer it filled, of the length it asked.
    let bytes = unsafe { std::slice::from_raw_parts(ptr, len) };
    match Player::new(bytes, seed as u64) {
        Ok(p) => {
            let n = p.categories().len() as i32;
            PLAYER.with(|s| *s.borrow_mut() = Some(p));
            n
        }
        Err(e) => fail(e),
    }
}

fn with_player(f: impl FnOnce(&mut Player) -> Result<i32, crate::PlayError>) -> i32 {
    PLAYER.with(|s| match s.borrow_mut().as_mut() {
        Some(p) => f(p).unwrap_or_else(fail),
        None => fail("no player: call play_new first"),
    })
}

/// The next frame with the keys held (`turn` −1 left … +1 right; flags 0 or
/// 1): 1, its values at [`play_frame`]; or 0.
#[unsafe(no_mangle)]
pub extern "C" fn play_step(turn: f32, go: i32, run: i32, stop: i32) -> i32 {
    let keys = Keys {
        turn: turn as f64,
        go: go != 0,
        run: run != 0,
        stop: stop != 0,
    };
    with_player(|p| {
        let f: Frame = p.step(keys)?;
        let category = p.category() as f32;
        FRAME.with(|out| {
            let mut out = out.borrow_mut();
            for (o, v) in out.iter_mut().zip(f.pose.iter().flatten()) {
                *o = *v as f32;
            }
            let rest = [
                f.root.pos[0],
                f.root.pos[1],
                f.root.forward[0],
                f.root.forward[1],
                f.heading[0],
                f.heading[1],
                f.speed,
            ];
            for (o, v) in out[3 * NUM_JOINTS..].iter_mut().zip(rest) {
                *o = v as f32;
            }
            out[FRAME_VALUES - 1] = category;
        });
        Ok(1)
    })
}

/// Asks category `i` from the next frame on (`restart` 1: from its context,
/// at the origin): 1, or 0.
#[unsafe(no_mangle)]
pub extern "C" fn play_pick(i: i32, restart: i32) -> i32 {
    with_player(|p| {
        let i = usize::try_from(i)
            .map_err(|_| crate::PlayError::Invalid(format!("no category {i}")))?;
        match restart != 0 {
            true => p.restart(i)?,
            false => p.pick(i)?,
        }
        Ok(1)
    })
}

/// Where the last frame's [`FRAME_VALUES`] values are.
#[unsafe(no_mangle)]
pub extern "C" fn play_frame() -> *const f32 {
    FRAME.with(|f| f.borrow().as_ptr())
}

/// The categories' names, comma-separated, at [`play_text`].
#[unsafe(no_mangle)]
pub extern "C" fn play_categories() -> i32 {
    PLAYER.with(|s| match s.borrow().as_ref() {
        Some(p) => {
            let names = p.categories().join(",");
            TEXT.with(|m| *m.borrow_mut() = names);
            1
        }
        None => fail("no player: call play_new first"),
    })
}

/// The last message (an error, or what [`play_categories`] wrote): its
/// bytes at [`play_text`], this many.
#[unsafe(no_mangle)]
pub extern "C" fn play_text_len() -> usize {
    TEXT.with(|m| m.borrow().len())
}

/// Where the last message's UTF-8 bytes are.
#[unsafe(no_mangle)]
pub extern "C" fn play_text() -> *const u8 {
    TEXT.with(|m| m.borrow().as_ptr())
}
