//! A stage's result reused from the stage cache when its key matches, else computed and
//! stored; and which of the two happened.

use serde::Serialize;
use serde::de::DeserializeOwned;

use super::{RunError, StageProgress, StageStatus};
use crate::cache::StageCache;

/// A stage's result: the one cached under `key` when there is one (and `valid`), else
/// `compute`d and cached. Says which.
pub(super) fn cached<T: Serialize + DeserializeOwned>(
    cache: &StageCache,
    progress: &dyn StageProgress,
    stage: &str,
    key: &str,
    valid: bool,
    compute: impl FnOnce() -> Result<T, RunError>,
) -> Result<(T, StageStatus), RunError> {
    if valid && let Some(d) = cache.load::<T>(stage, key) {
        return Ok((d, StageStatus::Reused));
    }
    let d = compute()?;
    cache.store(stage, key, &d)?;
    progress.stored(stage);
    Ok((d, StageStatus::Computed))
}

/// A stage whose data are a sequence written a piece at a time (its `compute` stores them with
/// [`StageCache::store_seq`] and gives their summary): the summary cached beside them (as
/// `STAGE-summary`) under the same key, the data left on disk. Reused only when both are
/// there whole under `key`.
pub(super) fn cached_seq<S: Serialize + DeserializeOwned>(
    cache: &StageCache,
    progress: &dyn StageProgress,
    stage: &str,
    key: &str,
    compute: impl FnOnce() -> Result<S, RunError>,
) -> Result<(S, StageStatus), RunError> {
    // The summary's key is not the data's: neither file passes for the other.
    let (summary, summary_key) = (format!("{stage}-summary"), format!("{key}/summary"));
    if cache.has(stage, key)
        && let Some(d) = cache.load::<S>(&summary, &summary_key)
    {
        return Ok((d, StageStatus::Reused));
    }
    let d = compute()?;
    cache.store(&summary, &summary_key, &d)?;
    progress.stored(stage);
    Ok((d, StageStatus::Computed))
}
