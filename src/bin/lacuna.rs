//! The `lacuna` command: render scenes (and, as the project grows, analyse and compare).

use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use clap::{Args, Parser, Subcommand};
use lacuna::film::ExrMetadata;
use lacuna::integrator::{self, IntegratorSettings, MisHeuristic};
use lacuna::math::Vec3;
use lacuna::render::{render, Progress, RenderSettings};
use lacuna::scene::{two_rooms_builder, Camera, Scene, SceneBuilder};

#[derive(Parser)]
#[command(
    name = "lacuna",
    version,
    about = "Lacuna: a physically based renderer that reads the empty space of a scene"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render a scene to an EXR or PNG file.
    ///
    /// Without SCENE, renders the built-in scene: two rooms joined by an ajar door, lit from
    /// the far room.
    Render(RenderArgs),
}

/// Options shared by every command that renders.
#[derive(Args, Clone, Debug)]
struct RenderArgs {
    /// An .obj file (framed automatically when no camera is given) or a .json scene file.
    scene: Option<PathBuf>,
    /// Integrator name (available: path).
    #[arg(long, default_value = "path")]
    integrator: String,
    /// Samples per pixel (default 16, or the scene file's).
    #[arg(long, conflicts_with = "time")]
    spp: Option<u32>,
    /// Render for this many seconds instead of a fixed sample count.
    #[arg(long)]
    time: Option<f64>,
    /// Maximum number of bounces (1 = direct lighting only).
    #[arg(long)]
    max_depth: Option<u32>,
    /// MIS heuristic between light and BSDF sampling: power or balance.
    #[arg(long, default_value = "power")]
    mis: String,
    #[arg(long)]
    width: Option<u32>,
    #[arg(long)]
    height: Option<u32>,
    /// Seed of the random sequences; the same seed and sample count give the same image.
    #[arg(long)]
    seed: Option<u64>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Camera position, as X,Y,Z.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    eye: Option<Vec3>,
    /// Point the camera looks at, as X,Y,Z.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    target: Option<Vec3>,
    /// Camera up vector, as X,Y,Z.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    up: Option<Vec3>,
    /// Vertical field of view in degrees.
    #[arg(long)]
    fov: Option<f32>,
    /// Output file: .exr (float32 with AOVs and metadata) or .png (sRGB preview).
    #[arg(long, short, default_value = "lacuna.png")]
    out: PathBuf,
    /// Exposure of PNG output in stops.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    exposure: f32,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

fn parse_vec3(s: &str) -> Result<Vec3, String> {
    let parts: Vec<&str> = s.split(',').collect();
    if parts.len() != 3 {
        return Err(format!("expected X,Y,Z, got '{s}'"));
    }
    let mut v = [0.0f32; 3];
    for (i, p) in parts.iter().enumerate() {
        v[i] = p.trim().parse::<f32>().map_err(|e| format!("'{p}': {e}"))?;
        if !v[i].is_finite() {
            return Err(format!("'{p}' is not finite"));
        }
    }
    Ok(Vec3::from(v))
}

/// A scene ready to render with the settings that came with it.
struct Prepared {
    scene: Scene,
    camera: Camera,
    render: RenderSettings,
    integrator: IntegratorSettings,
    integrator_name: String,
    label: String,
}

fn prepare(args: &RenderArgs) -> lacuna::Result<Prepared> {
    let (builder, label): (SceneBuilder, String) = match &args.scene {
        None => (two_rooms_builder()?, "built-in two rooms".into()),
        Some(path) => (load_builder(path)?, path.display().to_string()),
    };
    let scene = builder.build()?;
    let mut render = RenderSettings::default();
    if let Some(w) = args.width {
        render.width = w;
    }
    if let Some(h) = args.height {
        render.height = h;
    }
    if let Some(s) = args.spp {
        render.spp = s;
    }
    if let Some(t) = args.time {
        if !(t > 0.0 && t.is_finite()) {
            return Err(lacuna::Error::invalid(format!(
                "--time {t} must be a positive number of seconds"
            )));
        }
        render.time_limit = Some(Duration::from_secs_f64(t));
        render.spp = args.spp.unwrap_or(u32::MAX);
    }
    if let Some(s) = args.seed {
        render.seed = s;
    }
    render.threads = args.threads;
    let mut integrator = IntegratorSettings {
        mis: MisHeuristic::parse(&args.mis)?,
        ..Default::default()
    };
    if let Some(d) = args.max_depth {
        integrator.max_depth = d;
    }
    let camera = override_camera(scene.camera().copied(), args)?;
    Ok(Prepared {
        scene,
        camera,
        render,
        integrator,
        integrator_name: args.integrator.clone(),
        label,
    })
}

fn load_builder(path: &Path) -> lacuna::Result<SceneBuilder> {
    Err(lacuna::Error::invalid(format!(
        "cannot load {} yet",
        path.display()
    )))
}

fn override_camera(base: Option<Camera>, args: &RenderArgs) -> lacuna::Result<Camera> {
    let mut camera = base.unwrap_or(Camera::look_at(
        Vec3::new(0.0, 0.0, 5.0),
        Vec3::ZERO,
        Vec3::Y,
        40.0,
    )?);
    if let Some(e) = args.eye {
        camera.eye = e;
    }
    if let Some(t) = args.target {
        camera.target = t;
    }
    if let Some(u) = args.up {
        camera.up = u;
    }
    if let Some(f) = args.fov {
        camera.vfov_degrees = f;
    }
    camera.validate()?;
    Ok(camera)
}

/// A progress bar on standard error, redrawn at most ten times a second.
struct ProgressBar {
    enabled: bool,
    last: Mutex<Instant>,
}

impl ProgressBar {
    fn new(quiet: bool) -> Self {
        ProgressBar {
            enabled: !quiet && std::io::stderr().is_terminal(),
            last: Mutex::new(Instant::now()),
        }
    }

    fn update(&self, p: Progress) -> bool {
        if !self.enabled {
            return true;
        }
        let mut last = self.last.lock().unwrap_or_else(|e| e.into_inner());
        if last.elapsed() < Duration::from_millis(100) && p.fraction < 1.0 {
            return true;
        }
        *last = Instant::now();
        let width = 40;
        let filled = ((p.fraction.clamp(0.0, 1.0)) * width as f64) as usize;
        let mut err = std::io::stderr().lock();
        let _ = write!(
            err,
            "\r[{}{}] {:5.1}%  {} spp  {:.1} s ",
            "#".repeat(filled),
            " ".repeat(width - filled),
            p.fraction * 100.0,
            p.spp_done,
            p.elapsed.as_secs_f64()
        );
        if p.fraction >= 1.0 {
            let _ = writeln!(err);
        }
        true
    }
}

fn run_render(args: &RenderArgs) -> lacuna::Result<()> {
    let prep = prepare(args)?;
    let integrator = integrator::create(&prep.integrator_name, prep.integrator)?;
    let bar = ProgressBar::new(args.quiet);
    let cancel = AtomicBool::new(false);
    let (film, stats) = render(
        &prep.scene,
        &prep.camera,
        integrator.as_ref(),
        &prep.render,
        &|p| bar.update(p),
        &cancel,
    )?;
    write_film(&film, &args.out, args.exposure, &prep, stats.spp)?;
    println!(
        "{}: {}x{}, {} spp of {} (max depth {}) in {:.2} s: {:.2} M samples/s, {:.2} M rays/s -> {}",
        prep.label,
        prep.render.width,
        prep.render.height,
        stats.spp,
        prep.integrator_name,
        prep.integrator.max_depth,
        stats.seconds,
        stats.samples_per_second() / 1e6,
        stats.rays_per_second() / 1e6,
        args.out.display()
    );
    Ok(())
}

fn write_film(
    film: &lacuna::film::Film,
    out: &Path,
    exposure: f32,
    prep: &Prepared,
    spp: u32,
) -> lacuna::Result<()> {
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| lacuna::Error::io(dir, e))?;
    }
    match out
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .as_deref()
    {
        Some("exr") => {
            let meta = ExrMetadata::default()
                .with("spp", spp)
                .with("seed", prep.render.seed)
                .with("integrator", &prep.integrator_name)
                .with("max_depth", prep.integrator.max_depth)
                .with("scene", &prep.label);
            film.write_exr(out, &meta)
        }
        Some("png") => film.write_png(out, exposure),
        _ => Err(lacuna::Error::invalid(format!(
            "output {} must end in .exr or .png",
            out.display()
        ))),
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match &cli.command {
        Command::Render(args) => run_render(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("lacuna: {e}");
            ExitCode::FAILURE
        }
    }
}
