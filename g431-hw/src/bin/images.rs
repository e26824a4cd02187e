//! The image descriptions (`g431_hw::images`) for the tools around the firmware:
//!   images builds          one line per image ./test.sh builds: name, crate, features ("-" for none), flash and
//!                          static RAM budgets in bytes, the flash it is linked into (its FLASH region) in bytes, and
//!                          its stack budget in bytes
//!   images partitions      the flash map of every layout, region by region, for the size report
//!   images docs [--write]  the docs' generated tables; with --write, rewritten in place in docs/hardware.md
use std::process::ExitCode;

use g431_hw::images::{BUILDS, DOCS_TABLES, write_docs_table};
use g431_hw::memory::KIB;

const DOCS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/hardware.md");

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    match args.as_slice() {
        ["builds"] => {
            for build in BUILDS {
                let features = if build.features.is_empty() { "-" } else { build.features };
                let linked = build.layout.region("FLASH").map_or(0, |region| region.span.length);
                println!(
                    "{} {} {} {} {} {linked} {}",
                    build.name, build.package, features, build.flash_budget, build.ram_budget, build.stack_budget
                );
            }
            ExitCode::SUCCESS
        }
        ["partitions"] => {
            let mut shown = Vec::new();
            for build in BUILDS {
                if shown.contains(&build.layout) {
                    continue;
                }
                shown.push(build.layout);
                let chip = build.layout.chip;
                println!(
                    "{}, {} ({} KiB of flash)",
                    build.layout.image,
                    chip.part,
                    chip.flash.length / KIB
                );
                for region in build
                    .layout
                    .regions
                    .iter()
                    .filter(|region| chip.flash.contains(region.span))
                {
                    let span = region.span;
                    println!(
                        "  {:<16} 0x{:08X}-0x{:08X} {:>3} KiB  {}",
                        region.name,
                        span.origin,
                        span.end(),
                        span.length / KIB,
                        region.holds
                    );
                }
            }
            ExitCode::SUCCESS
        }
        ["docs"] => {
            for name in DOCS_TABLES {
                println!("<!-- generated: {name} -->\n{}<!-- end -->\n", table(name));
            }
            ExitCode::SUCCESS
        }
        ["docs", "--write"] => match rewrite_docs() {
            Ok(()) => ExitCode::SUCCESS,
            Err(error) => {
                eprintln!("images: {error}");
                ExitCode::FAILURE
            }
        },
        _ => {
            eprintln!("usage: images builds | images partitions | images docs [--write]");
            ExitCode::from(2)
        }
    }
}

fn table(name: &str) -> String {
    let mut text = String::new();
    // Writing into a String cannot fail, and every name in DOCS_TABLES is known.
    let _ = write_docs_table(name, &mut text);
    text
}

/// Replace each generated table in docs/hardware.md between its markers.
fn rewrite_docs() -> Result<(), String> {
    let mut docs = std::fs::read_to_string(DOCS).map_err(|error| format!("{DOCS}: {error}"))?;
    for name in DOCS_TABLES {
        let open = format!("<!-- generated: {name} -->\n");
        let start = docs.find(&open).ok_or(format!("{DOCS} has no {open:?}"))? + open.len();
        let end = docs
            .get(start..)
            .and_then(|rest| rest.find("<!-- end -->"))
            .ok_or(format!("{DOCS}: {name} has no end marker"))?;
        docs.replace_range(start..start + end, &table(name));
    }
    std::fs::write(DOCS, docs).map_err(|error| format!("{DOCS}: {error}"))?;
    println!("{DOCS}: {} tables written", DOCS_TABLES.len());
    Ok(())
}
