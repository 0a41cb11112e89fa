//! `brdfpack eval`: PLACEHOLDER until the models work lands.

use clap::Args;

#[derive(Args, Debug)]
pub struct EvalArgs {
    /// Model spec or table file.
    pub source: String,
}

pub fn run(args: EvalArgs) -> anyhow::Result<i32> {
    let _ = crate::model::Model::parse(&args.source)?;
    Err(crate::Error::Failure("eval is not implemented yet".into()).into())
}
