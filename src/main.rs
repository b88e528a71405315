//! The `puppetry` command line: argument parsing and error reporting only;
//! the work is in the library (`puppetry::cli` and below).

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::{Parser, Subcommand};
use puppetry::cli;

#[derive(Parser)]
#[command(
    name = "puppetry",
    version,
    about = "Realtime 2D puppetry: meshing, as-rigid-as-possible deformation"
)]
struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Build a triangle mesh from a PNG (traced from its alpha channel) or a
    /// polygon JSON file; writes `.mesh.json` (see docs/mesh-format.md).
    Mesh {
        /// A .png picture or a .json polygon.
        input: PathBuf,
        /// Target vertex count (the result lands within ±15%).
        #[arg(long)]
        vertices: Option<usize>,
        /// Output file; standard output when absent.
        #[arg(short, long)]
        output: Option<PathBuf>,
    },
    /// Deform a mesh by handles and print {"vertices": [[x, y], …]}.
    Solve {
        #[arg(long)]
        mesh: PathBuf,
        /// {"handles": [{"vertex": i, "to": [x, y]} | {"point": [x, y], "to": [x, y]}, …]}
        #[arg(long)]
        handles: PathBuf,
        /// Print the scale-free intermediate result of step 1.
        #[arg(long)]
        step1_only: bool,
        /// Also draw the rest and deformed meshes to this SVG file.
        #[arg(long)]
        svg: Option<PathBuf>,
    },
    /// Time registration, compilation, updates and handle changes.
    Bench {
        /// One JSON object per case, one per line.
        #[arg(long)]
        json: bool,
        /// Bench this mesh instead of the demo puppet at several sizes.
        #[arg(long)]
        mesh: Option<PathBuf>,
        /// Vertex counts to mesh the demo puppet at.
        #[arg(long, value_delimiter = ',', default_value = "1000,10000,100000")]
        sizes: Vec<usize>,
        /// Handle counts to bench.
        #[arg(long, value_delimiter = ',', default_value = "2,10,40")]
        handles: Vec<usize>,
    },
}

fn main() -> ExitCode {
    match run(Args::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            // Our messages already quote their cause; print each link of the
            // chain only when it adds something.
            let mut message = String::new();
            for link in error.chain() {
                let text = link.to_string();
                if !message.contains(&text) {
                    if !message.is_empty() {
                        message.push_str(": ");
                    }
                    message.push_str(&text);
                }
            }
            eprintln!("error: {message}");
            ExitCode::FAILURE
        }
    }
}

fn run(args: Args) -> anyhow::Result<()> {
    match args.command {
        Command::Mesh {
            input,
            vertices,
            output,
        } => {
            let mesh = cli::mesh_command(&input, vertices)?;
            let pieces = mesh.pieces().len();
            let text = mesh.to_json();
            match output {
                Some(path) => cli::write(&path, &text)?,
                None => println!("{text}"),
            }
            eprintln!(
                "meshed {}: {} vertices, {} triangles, {} piece(s)",
                input.display(),
                mesh.vertices().len(),
                mesh.triangles().len(),
                pieces
            );
        }
        Command::Solve {
            mesh,
            handles,
            step1_only,
            svg,
        } => {
            let out = cli::solve_command(&mesh, &handles, step1_only, svg.as_deref())?;
            println!("{out}");
        }
        Command::Bench {
            json,
            mesh,
            sizes,
            handles,
        } => {
            let meshes =
                cli::bench_meshes(mesh.as_deref(), &sizes).context("preparing bench meshes")?;
            let stdout = std::io::stdout();
            cli::bench_command(&meshes, &handles, json, |line| {
                let mut out = stdout.lock();
                let _ = writeln!(out, "{line}");
                let _ = out.flush();
            })?;
        }
    }
    Ok(())
}
