//! Independent items (episodes, ranked states, branched episodes) on several threads, results in
//! item order: the one loop behind every multi-threaded evaluation of this crate and the trainer.
//! Each thread builds its own state (an environment, a network's scratch) once; items are handed
//! out one at a time, so a slow item does not hold up a whole share. An item's result depends on
//! its index alone, never on the thread that ran it, so the result does not depend on the thread
//! count.

use std::sync::atomic::{AtomicUsize, Ordering};

/// What one thread ran: its items' results with their indices, and its error with its item's.
type Share<T, E> = (Vec<(usize, T)>, Option<(usize, E)>);

/// Runs `run(&mut state, i)` for every `i` in `0..items` on `threads` threads (at least one, at
/// most one per item), each thread's `state` made by `init`; calls `on_item` after each item.
/// Returns the results in item order, or the error of the first failing item in item order
/// (every thread stops at its first error).
pub fn map_in_order<S, T, E>(
    items: usize,
    threads: usize,
    init: impl Fn() -> Result<S, E> + Sync,
    run: impl Fn(&mut S, usize) -> Result<T, E> + Sync,
    on_item: &(dyn Fn() + Sync),
) -> Result<Vec<T>, E>
where
    T: Send,
    E: Send,
{
    let next = AtomicUsize::new(0);
    let threads = threads.clamp(1, items.max(1));
    let results: Vec<Share<T, E>> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads)
            .map(|_| {
                s.spawn(|| {
                    let mut out = Vec::new();
                    let mut state = match init() {
                        Ok(st) => st,
                        Err(e) => return (out, Some((0, e))),
                    };
                    loop {
                        let i = next.fetch_add(1, Ordering::Relaxed);
                        if i >= items {
                            return (out, None);
                        }
                        match run(&mut state, i) {
                            Ok(t) => out.push((i, t)),
                            Err(e) => return (out, Some((i, e))),
                        }
                        on_item();
                    }
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().unwrap_or_else(|p| std::panic::resume_unwind(p)))
            .collect()
    });
    let mut all = Vec::with_capacity(items);
    let mut first_error: Option<(usize, E)> = None;
    for (out, err) in results {
        all.extend(out);
        if let Some((i, e)) = err
            && first_error.as_ref().is_none_or(|(j, _)| i < *j)
        {
            first_error = Some((i, e));
        }
    }
    if let Some((_, e)) = first_error {
        return Err(e);
    }
    all.sort_by_key(|&(i, _)| i);
    Ok(all.into_iter().map(|(_, t)| t).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn results_come_in_item_order_on_any_thread_count() {
        for threads in [0, 1, 2, 3, 8, 100] {
            let got: Result<Vec<usize>, ()> =
                map_in_order(37, threads, || Ok(()), |_, i| Ok(i * i), &|| {});
            assert_eq!(got.unwrap(), (0..37).map(|i| i * i).collect::<Vec<_>>());
        }
        let none: Result<Vec<u8>, ()> = map_in_order(0, 4, || Ok(()), |_, _| Ok(1), &|| {});
        assert!(none.unwrap().is_empty());
    }

    #[test]
    fn the_first_failing_item_is_the_error() {
        for threads in [1, 2, 4] {
            let got: Result<Vec<usize>, usize> = map_in_order(
                20,
                threads,
                || Ok(()),
                |_, i| if i % 7 == 5 { Err(i) } else { Ok(i) },
                &|| {},
            );
            assert_eq!(got, Err(5), "{threads} threads");
        }
        let got: Result<Vec<usize>, &str> =
            map_in_order(3, 2, || Err("no state"), |_: &mut (), i| Ok(i), &|| {});
        assert_eq!(got, Err("no state"));
    }
}
