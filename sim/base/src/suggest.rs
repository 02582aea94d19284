//! "Did you mean" suggestions for unknown keys and names.
//!
//! Model: the Levenshtein edit distance (insertions, deletions, substitutions, each costing
//! 1) between the unknown word and every valid one; the nearest valid word is suggested if
//! it is within a third of the longer word's length (at least 1, at most 4 edits), so a typo
//! gets a suggestion and an unrelated word none. Ties go to the first candidate in the
//! caller's order.

/// Edit distance between `a` and `b` (by characters).
pub fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut prev: Vec<usize> = (0..=b.len()).collect();
    let mut cur = vec![0; b.len() + 1];
    for (i, ca) in a.chars().enumerate() {
        cur[0] = i + 1;
        for (j, &cb) in b.iter().enumerate() {
            let sub = prev[j] + usize::from(ca != cb);
            cur[j + 1] = sub.min(prev[j + 1] + 1).min(cur[j] + 1);
        }
        std::mem::swap(&mut prev, &mut cur);
    }
    prev[b.len()]
}

/// The valid word nearest to `word`, if it is close enough to be a likely typo.
pub fn nearest<'a>(word: &str, candidates: impl IntoIterator<Item = &'a str>) -> Option<&'a str> {
    let mut best: Option<(usize, &str)> = None;
    for c in candidates {
        let d = edit_distance(word, c);
        if best.is_none_or(|(bd, _)| d < bd) {
            best = Some((d, c));
        }
    }
    let (d, c) = best?;
    let longer = word.chars().count().max(c.chars().count());
    (d >= 1 && d <= (longer / 3).clamp(1, 4)).then_some(c)
}

/// `"; did you mean KEY?"` for the nearest candidate, or an empty string.
pub fn did_you_mean<'a>(word: &str, candidates: impl IntoIterator<Item = &'a str>) -> String {
    nearest(word, candidates).map_or(String::new(), |c| format!("; did you mean {c}?"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distances() {
        assert_eq!(edit_distance("", "abc"), 3);
        assert_eq!(edit_distance("kitten", "sitting"), 3);
        assert_eq!(edit_distance("thicknes_mm", "thickness_mm"), 1);
        assert_eq!(edit_distance("same", "same"), 0);
    }

    #[test]
    fn typos_get_the_nearest_key_and_unrelated_words_none() {
        let keys = ["thickness_mm", "glass", "absorption_per_mm"];
        assert_eq!(nearest("thicknes_mm", keys), Some("thickness_mm"));
        assert_eq!(nearest("glas", keys), Some("glass"));
        assert_eq!(nearest("colour", keys), None);
        assert_eq!(
            nearest("glass", keys),
            None,
            "an exact match is not a suggestion"
        );
        assert_eq!(
            did_you_mean("plat", ["plate", "hoe"]),
            "; did you mean plate?"
        );
        assert_eq!(did_you_mean("zzz", ["plate", "hoe"]), "");
    }
}
