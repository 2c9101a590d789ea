//! One copy of a tuning for every tracker built with it.
//!
//! A daemon builds a tracker per aircraft, all from the same configuration, and each held
//! its own copy of the tuning: about 1.7 KB of parameters (the hybrid's, its IMM's, its
//! gate's) per aircraft, a tenth of an aircraft's memory at fleet scale. [`shared`] hands
//! out one `Arc` per distinct value instead. Constructors keep taking plain values, so a
//! test or a benchmark that builds its own tuning is unaffected.

use std::any::Any;
use std::sync::{Arc, Mutex};

/// Distinct values kept. A process uses a handful (one per tracker kind and tuning); past
/// this, values are still returned, each in an `Arc` of its own.
const MAX_SHARED: usize = 64;

/// The values handed out so far, of any type.
static SHARED: Mutex<Vec<Arc<dyn Any + Send + Sync>>> = Mutex::new(Vec::new());

/// `value` in an `Arc` shared with every earlier call given an equal value of the same
/// type. A value unequal to itself (a NaN in it) is never shared, only wrapped.
pub fn shared<T: PartialEq + Send + Sync + 'static>(value: T) -> Arc<T> {
    let Ok(mut list) = SHARED.lock() else {
        return Arc::new(value);
    };
    for held in list.iter() {
        if let Ok(same) = Arc::clone(held).downcast::<T>() {
            if *same == value {
                return same;
            }
        }
    }
    let new = Arc::new(value);
    // (A value unequal to itself would only fill the list.)
    #[allow(clippy::eq_op)]
    let comparable = *new == *new;
    if comparable && list.len() < MAX_SHARED {
        list.push(new.clone());
    }
    new
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, PartialEq)]
    struct Tuning(f64, u32);

    #[test]
    fn equal_values_share_one_copy_and_unequal_ones_do_not() {
        let a = shared(Tuning(1.5, 7));
        let b = shared(Tuning(1.5, 7));
        assert!(Arc::ptr_eq(&a, &b));
        let c = shared(Tuning(1.5, 8));
        assert!(!Arc::ptr_eq(&a, &c));
        assert_eq!(*c, Tuning(1.5, 8));
        // Another type with the same bits is another value.
        let d = shared((1.5f64, 7u32));
        assert_eq!(d.0, 1.5);
        // A NaN never equals itself: wrapped, not shared.
        let e = shared(Tuning(f64::NAN, 1));
        let f = shared(Tuning(f64::NAN, 1));
        assert!(!Arc::ptr_eq(&e, &f) && e.0.is_nan());
    }
}
