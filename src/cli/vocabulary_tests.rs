//! Issue #22: one flag vocabulary, on the clap definition (not a hand list): every
//! subcommand accepts `-o`, `--json`, `-q` and `-v`. (tests/cli_vocabulary.rs runs the
//! binary for the rest.)

use super::Cli;
use clap::CommandFactory;

fn subcommands() -> Vec<clap::Command> {
    Cli::command().get_subcommands().cloned().collect()
}

#[test]
fn every_subcommand_has_the_vocabulary() {
    let subs = subcommands();
    assert!(subs.len() >= 14, "{} subcommands", subs.len());
    for sub in &subs {
        let name = sub.get_name();
        let arg = |long: &str| sub.get_arguments().find(|a| a.get_long() == Some(long));
        for (long, short) in [
            ("json", None),
            ("quiet", Some('q')),
            ("verbose", Some('v')),
            ("output", Some('o')),
        ] {
            let a = arg(long).unwrap_or_else(|| panic!("{name}: no --{long}"));
            if let Some(s) = short {
                assert_eq!(a.get_short(), Some(s), "{name} --{long}");
            }
        }
        // -q and -v are flags; --json is a flag.
        for long in ["json", "quiet", "verbose"] {
            assert!(
                !arg(long).unwrap().get_action().takes_values(),
                "{name} --{long} takes no value"
            );
        }
    }
}

#[test]
fn bench_keeps_out_as_an_alias_of_output() {
    let bench = Cli::command().find_subcommand("bench").cloned().unwrap();
    let out = bench
        .get_arguments()
        .find(|a| a.get_long() == Some("output"))
        .unwrap();
    assert!(
        out.get_all_aliases().is_some_and(|a| a.contains(&"out")),
        "--out alias kept"
    );
}
