//! One definition per option: the enums behind the CLI's choices (`--sampler`, `--user-side`,
//! ...) derive `clap::ValueEnum`, and the Python module parses its string arguments with
//! [`parse`], so clap, serde (kebab-case names) and Python accept the same names and print the
//! same list. Built with the `clap` feature (the CLI crate turns it on).

use clap::ValueEnum;

/// `value` parsed as one of `T`'s names (as on the command line), or the one-line message
/// `WHAT "VALUE": expected "a", "b" or "c"`.
pub fn parse<T: ValueEnum>(what: &str, value: &str) -> Result<T, String> {
    T::from_str(value, false).map_err(|_| format!("{what} {value:?}: expected {}", names::<T>()))
}

/// `"a", "b" or "c"`: the names `T` accepts.
pub fn names<T: ValueEnum>() -> String {
    let n: Vec<String> = T::value_variants()
        .iter()
        .filter_map(|v| v.to_possible_value().map(|p| format!("{:?}", p.get_name())))
        .collect();
    match n.split_last() {
        Some((last, rest)) if !rest.is_empty() => format!("{} or {last}", rest.join(", ")),
        Some((last, _)) => last.clone(),
        None => String::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampler::SamplerKind;

    #[test]
    fn names_and_messages_match_the_command_line() {
        assert_eq!(
            parse::<SamplerKind>("sampler", "sobol"),
            Ok(SamplerKind::Sobol)
        );
        assert_eq!(
            parse::<SamplerKind>("sampler", "halton"),
            Err(r#"sampler "halton": expected "lattice", "independent" or "sobol""#.into())
        );
        // The serde name of every variant is the name clap and Python accept.
        for v in SamplerKind::value_variants() {
            let serde_name = serde_json::to_value(v).unwrap();
            let clap_name = v.to_possible_value().unwrap().get_name().to_string();
            assert_eq!(serde_name, serde_json::Value::String(clap_name));
        }
    }
}
