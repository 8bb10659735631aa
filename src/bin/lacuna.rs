//! The `lacuna` command: render scenes, make reference images and compare integrators at equal
//! time.

use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use clap::{Args, Parser, Subcommand};
use lacuna::analysis::Resolution;
use lacuna::compare::{compare_scheduled, render_reference, write_report, Contender, Schedule};
use lacuna::film::{ExrMetadata, Film, ImageErrors};
use lacuna::guide::SkeletonGuideSettings;
use lacuna::integrator::{self, MisHeuristic};
use lacuna::light::{EnvSettings, EnvStrategy, EnvironmentMap, UpAxis};
use lacuna::math::{SamplerKind, Vec3};
use lacuna::render::settings::{
    resolve, resolve_camera, ResolvedSettings, SettingsOverrides, DEFAULT_INTEGRATOR,
};
use lacuna::render::{render, Progress};
use lacuna::scene::{
    convert_layout, load_scene_arg, two_rooms_builder, Camera, RenderSettingsFile, Scene,
    SceneBuilder,
};
use lacuna::{Error, Result};

#[derive(Parser)]
#[command(
    name = "lacuna",
    version,
    about = "Lacuna: a physically based renderer that reads the empty space of a scene",
    after_help = "SCENE is an .obj file (framed automatically when no camera is given), a .json scene \
                  file (docs/scene-format.md), or a built-in scene: two-rooms (the default: two rooms \
                  joined by an ajar door, lit from the far room), corridor, interior (a house lit by the sky through \
                  windows; interior:windows=N, the same with N small windows), or rooms:SEED (a procedural \
                  family of interiors, see `lacuna family`)."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render a scene to an EXR or PNG file.
    Render(RenderArgs),
    /// Render a high-sample reference image (EXR) with an estimate of its own error.
    Reference(ReferenceArgs),
    /// Run integrators for the same wall-clock time and report their error against a reference.
    Compare(CompareArgs),
    /// Analyse the empty space: voxelization, distance and opening maps, regions and portals.
    Analyze(AnalyzeArgs),
    /// Describe scenes of the procedural family `rooms:SEED` (one line each), and optionally
    /// write them as OBJ + MTL + scene file for other renderers.
    Family(FamilyArgs),
    /// Bake the light field of a modelled luminaire (a scene file with a "capture" block,
    /// docs/light-field.md) by path tracing its geometry, into an EXR a scene's light_field
    /// light reads.
    CaptureLuminaire(CaptureArgs),
}

#[derive(Args, Clone, Debug)]
struct CaptureArgs {
    /// The luminaire file (.json).
    luminaire: PathBuf,
    /// The light field to write (.exr).
    #[arg(long)]
    out: PathBuf,
    /// Paths per texel (per pixel of each basis function's image) [default: the file's, or 64].
    #[arg(long)]
    samples: Option<u32>,
    /// Pixels per image, as RX or RXxRY [default: the file's].
    #[arg(long, value_parser = parse_pair)]
    resolution: Option<[u32; 2]>,
    /// Basis functions on the filter plane, as NX or NXxNY, spanning the file's first to last
    /// node [default: the file's].
    #[arg(long, value_parser = parse_pair)]
    nodes: Option<[u32; 2]>,
    /// Seed of the random sequences.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Worker threads [default: all cores].
    #[arg(long)]
    threads: Option<usize>,
}

/// "N" or "AxB" as a pair of counts.
fn parse_pair(text: &str) -> std::result::Result<[u32; 2], String> {
    let number = |t: &str| {
        t.trim()
            .parse::<u32>()
            .map_err(|_| format!("'{text}' is not N or NxM"))
    };
    match text.split_once(['x', 'X']) {
        Some((a, b)) => Ok([number(a)?, number(b)?]),
        None => {
            let n = number(text)?;
            Ok([n, n])
        }
    }
}

/// Peak resident memory of this process in bytes (Linux `VmHWM`), when the system says.
fn peak_resident_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

fn run_capture(args: &CaptureArgs) -> Result<()> {
    if args.out.extension().and_then(|e| e.to_str()) != Some("exr") {
        return Err(Error::invalid(format!(
            "--out {}: a light field is written as .exr",
            args.out.display()
        )));
    }
    let luminaire = lacuna::render::capture::load_luminaire(&args.luminaire)?;
    let mut settings = luminaire.settings;
    if let Some(nodes) = args.nodes {
        settings = settings.with_nodes(nodes);
    }
    if let Some(resolution) = args.resolution {
        settings.layout.resolution = resolution;
    }
    if let Some(samples) = args.samples {
        settings.samples = samples;
    }
    settings.seed = args.seed;
    settings.threads = args.threads;
    let l = &settings.layout;
    println!(
        "capturing {}: {}x{} {} basis functions, {}x{} pixels per image, {} paths per texel",
        args.luminaire.display(),
        l.nodes[0],
        l.nodes[1],
        l.basis.name(),
        l.resolution[0],
        l.resolution[1],
        settings.samples
    );
    let (field, stats) = lacuna::render::capture::capture(&luminaire.scene, &settings)?;
    field.write(&args.out)?;
    let mib = |b: f64| b / (1024.0 * 1024.0);
    println!(
        "captured in {:.2} s: {:.2} M paths ({:.2} M paths/s, {:.2} M rays); light field {:.2} MiB in memory, luminaire scene {:.2} MiB, peak resident {}",
        stats.seconds,
        stats.paths as f64 * 1e-6,
        stats.paths as f64 * 1e-6 / stats.seconds.max(1e-9),
        stats.rays as f64 * 1e-6,
        mib(stats.field_bytes as f64),
        mib(stats.scene_bytes as f64),
        peak_resident_bytes().map_or("unknown".to_string(), |b| format!("{:.1} MiB", mib(b as f64)))
    );
    println!(
        "wrote {} (power {:.4} W in luminance)",
        args.out.display(),
        field.power()
    );
    Ok(())
}

#[derive(Args, Clone, Debug)]
struct FamilyArgs {
    /// First seed.
    seed: u64,
    /// Number of consecutive seeds.
    #[arg(long, default_value_t = 1)]
    count: u64,
    /// Write rooms-SEED.obj, .mtl and .json into this directory.
    #[arg(long)]
    out: Option<PathBuf>,
}

fn run_family(args: &FamilyArgs) -> Result<()> {
    for seed in args.seed..args.seed.saturating_add(args.count) {
        let scene = lacuna::scene::FamilyScene::generate(seed);
        println!("{}", scene.description());
        if let Some(dir) = &args.out {
            let json = scene.write_files(dir)?;
            println!("  -> {}", json.display());
        }
    }
    Ok(())
}

/// Scene, camera, image and path options shared by every command.
#[derive(Args, Clone, Debug)]
struct SceneArgs {
    /// .obj file, .json scene file, or built-in scene name (two-rooms, corridor, interior, interior:windows=N, rooms:SEED). Default: two-rooms.
    scene: Option<PathBuf>,
    /// Maximum number of bounces (1 = direct lighting only) [default: 8, or the scene file's].
    #[arg(long)]
    max_depth: Option<u32>,
    /// MIS heuristic between light and BSDF sampling: power or balance; path, path_skeleton, path_portal and env_direct also auto (the per-pixel / per-point sample split of thesis 001 ch. 5; path_skeleton also re-estimates its guiding probability per node), env_direct also optimal (Kondapaneni et al. 2019) [default: power; env_direct: balance].
    #[arg(long)]
    mis: Option<String>,
    /// Bidirectional integrators: light subpaths per iteration [default: one per pixel].
    #[arg(long)]
    light_paths: Option<u32>,
    /// Image width in pixels [default: 512, or the scene file's].
    #[arg(long)]
    width: Option<u32>,
    /// Image height in pixels [default: 512, or the scene file's].
    #[arg(long)]
    height: Option<u32>,
    /// Seed of the random sequences; the same seed and sample count give the same image.
    #[arg(long)]
    seed: Option<u64>,
    /// Numbers of the pixel samples: sobol (Owen-scrambled Sobol, stratified over each pixel's
    /// samples, best at powers of two) or independent [default: sobol, or the scene file's].
    /// A compare contender option such as `path:sampler=independent` overrides it.
    #[arg(long)]
    sampler: Option<String>,
    /// Worker threads [default: all cores].
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
    /// Environment map lighting the scene from infinity (.exr or .hdr; 2:1 lat-long or 4:3
    /// horizontal cross of cube faces); replaces the scene file's.
    #[arg(long)]
    env: Option<PathBuf>,
    /// Radiance multiplier of the environment map.
    #[arg(long)]
    env_scale: Option<f32>,
    /// Rotation of the environment map about the up axis, in degrees.
    #[arg(long, allow_hyphen_values = true)]
    env_rotate: Option<f32>,
    /// World axis that is up for the environment map: y or z.
    #[arg(long)]
    env_up: Option<String>,
    /// Hide the environment map from camera rays (it still lights the scene).
    #[arg(long)]
    env_hidden: bool,
    /// Resample the environment map to this layout after loading: latlong or cube (faces of
    /// width / 4, the thesis's setting for the per-face CDFs).
    #[arg(long)]
    env_layout: Option<String>,
    /// How light sampling picks environment directions: auto (the default: latlong for a
    /// lat-long map, cube-dynamic for a cube map), latlong, cube-uniform, cube-power,
    /// cube-dynamic (per-normal face balancing), bsdf (no light sampling) or portals
    /// (path, path_skeleton and path_portal: through the window portals a point sees, found
    /// automatically or listed in the scene file). An integrator option such as
    /// `path:env=latlong` overrides it for that integrator.
    #[arg(long)]
    env_strategy: Option<String>,
    /// env_direct: light samples per shading point and light source (the environment, each emissive surface, the delta lights) [default: 30].
    #[arg(long)]
    env_samples: Option<u32>,
    /// env_direct: BSDF samples per shading point and light source [default: 30].
    #[arg(long)]
    env_bsdf_samples: Option<u32>,
    /// Thin-lens radius (0 = pinhole) [default: the scene file's, else 0].
    #[arg(long, allow_hyphen_values = true)]
    lens_radius: Option<f32>,
    /// Distance of the plane in focus, for a thin lens [default: the scene file's, else the
    /// distance from eye to target].
    #[arg(long)]
    focus_distance: Option<f32>,
    /// path_skeleton: probability c_skel of sampling the skeleton lobes instead of the BSDF,
    /// in [0, 1), or `learned` (per node, from a training pass from the camera; 0.5 where
    /// the scene has no camera) [default: learned].
    #[arg(long)]
    c_skel: Option<String>,
    /// path_skeleton: skeleton strength s (power-cosine exponent): a number >= 0, `auto`
    /// (per point, from the free-space radius and the distance to the importance point) or
    /// `auto:MAX`, or `learned` (per node, from a training pass whose proposal is auto:64;
    /// implies the lobes, `directions=lobes`) [default: auto:64].
    #[arg(long)]
    skel_strength: Option<String>,
    /// path_skeleton: analysis voxels along the longest axis of the scene [default: a budget
    /// of 2^20 voxels, see --skel-voxel-budget].
    #[arg(long, conflicts_with = "skel_voxel_budget")]
    skel_resolution: Option<u32>,
    /// path_skeleton: most voxels in the analysis grid [default: 1048576].
    #[arg(long)]
    skel_voxel_budget: Option<u64>,
    /// path_skeleton: rays traced from the lights to find the importance nodes [default: 16384].
    #[arg(long)]
    skel_light_rays: Option<u32>,
    /// path_skeleton: lobes per skeleton node, 1..=8 [default: 4].
    #[arg(long)]
    skel_lobes: Option<u32>,
    /// path_skeleton: keep lobes whose importance point is hidden from the shading point
    /// (saves one shadow ray per lobe and point).
    #[arg(long)]
    skel_no_visibility: bool,
    /// Refuse films (and environment maps) needing more memory than this many MiB; at most
    /// the machine's physical memory (docs/limits.md).
    #[arg(long, default_value_t = lacuna::limits::DEFAULT_MEMORY_BUDGET >> 20)]
    memory_budget_mib: u64,
    /// Render a scene without geometry or environment (black) instead of refusing it.
    #[arg(long)]
    allow_empty: bool,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
    /// Print build statistics and memory per structure.
    #[arg(long, short)]
    verbose: bool,
}

#[derive(Args, Clone, Debug)]
struct RenderArgs {
    #[command(flatten)]
    scene: SceneArgs,
    #[arg(long, help = integrator_help())]
    integrator: Option<String>,
    /// Samples per pixel [default: 16, or the scene file's].
    #[arg(long, conflicts_with = "time")]
    spp: Option<u32>,
    /// Render progressively for this many seconds instead of a fixed sample count.
    #[arg(long)]
    time: Option<f64>,
    /// bdpt only: render just the strategy with S light and T camera vertices (as S,T), for
    /// per-strategy debugging images.
    #[arg(long, value_name = "S,T")]
    strategy: Option<String>,
    /// With --strategy: without MIS weights.
    #[arg(long, requires = "strategy")]
    unweighted: bool,
    /// bdpt only: also write, from the same render, the image of every (s, t) strategy into
    /// this directory, weighted and unweighted (sS_tT_weighted.exr, sS_tT_unweighted.exr, with
    /// PNG previews), and weighted.png / unweighted.png sheets with one row per path length
    /// (000 Figure 22). Each strategy image costs 48 bytes per pixel while rendering.
    #[arg(long, value_name = "DIR")]
    strategy_images: Option<PathBuf>,
    /// With --strategy-images: longest path (segments) whose strategies get images [default:
    /// the maximum path length, max depth + 1].
    #[arg(long, requires = "strategy_images")]
    strategy_max_length: Option<u32>,
    /// Output file: .exr (float32 RGB with AOVs and metadata) or .png (sRGB preview).
    #[arg(long, short, default_value = "lacuna.png")]
    out: PathBuf,
    /// Exposure of PNG output, in stops.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    exposure: f32,
}

#[derive(Args, Clone, Debug)]
struct ReferenceArgs {
    #[command(flatten)]
    scene: SceneArgs,
    /// Integrator name [default: path].
    #[arg(long)]
    integrator: Option<String>,
    /// Samples per pixel (rendered as two independent halves).
    #[arg(long)]
    spp: u32,
    /// Output EXR file.
    #[arg(long, short)]
    out: PathBuf,
}

#[derive(Args, Clone, Debug)]
struct CompareArgs {
    #[command(flatten)]
    scene: SceneArgs,
    #[arg(long, default_value = "path", help = contenders_help())]
    integrators: String,
    /// Seconds per integrator per run.
    #[arg(long)]
    time: f64,
    /// Reference EXR (from `lacuna reference`) of the same scene, camera and size.
    #[arg(long)]
    reference: PathBuf,
    /// Output directory (curves.csv, convergence.svg, summary.md, images).
    #[arg(long, short)]
    out: PathBuf,
    /// Runs per integrator [default: 3 when the budget allows (three runs' wall-clock time <= 30 min), else 1].
    #[arg(long)]
    runs: Option<u32>,
    /// Run the integrators of each run at the same time, each with --threads workers, instead
    /// of one after the other: on a shared machine whose load swings, all meet the same load,
    /// so their ratios hold (each gets about 1 / (integrators) of the machine).
    #[arg(long)]
    concurrent: bool,
}

#[derive(Args, Clone, Debug)]
struct AnalyzeArgs {
    /// .obj file, .json scene file, or built-in scene name (two-rooms, corridor, interior, interior:windows=N, rooms:SEED). Default: two-rooms.
    scene: Option<PathBuf>,
    /// Voxels along the longest axis of the scene bounds.
    #[arg(long, default_value_t = 128, conflicts_with_all = ["voxel_size", "voxel_budget"])]
    resolution: u32,
    /// Voxel edge length in world units (instead of --resolution).
    #[arg(long)]
    voxel_size: Option<f64>,
    /// Largest number of voxels (instead of --resolution).
    #[arg(long)]
    voxel_budget: Option<u64>,
    /// Treat the inside of closed objects as occupied.
    #[arg(long)]
    fill_interiors: bool,
    /// Treat the outside of the grid as empty (default: solid).
    #[arg(long)]
    outside_empty: bool,
    /// Also compute L1 and Euclidean distance maps, the L1 opening and the decenterness map.
    #[arg(long)]
    all_maps: bool,
    /// Also compute the curvilinear skeleton of the empty space (implies --all-maps): writes
    /// skeleton.obj / skeleton_filtered.obj (lines), skeleton.ply / skeleton_filtered.ply (with
    /// a radius per vertex), skeleton.png and node_map.png, and adds skeleton, empty_space and
    /// skeleton_seconds to the JSON summary.
    #[arg(long)]
    skeleton: bool,
    /// With --skeleton: gather free pairs on one thread (the result is identical).
    #[arg(long)]
    skeleton_sequential: bool,
    /// With --skeleton: skip the Betti numbers of the empty space (saves two grid passes).
    #[arg(long)]
    no_topology: bool,
    /// With --skeleton: skip skeleton.png and node_map.png.
    #[arg(long)]
    no_images: bool,
    /// Also find the window portals for environment light (`path:env=portals`): openings
    /// between enclosed regions and the outside, fitted with rectangles (an analysis of its
    /// own, 192 voxels along the longest axis, insides of closed objects filled); listed as
    /// window_portals in the JSON summary and drawn over the camera's view in
    /// window_portals.png.
    #[arg(long)]
    window_portals: bool,
    /// Refuse grids needing more memory than this many MiB.
    #[arg(long, default_value_t = 4096)]
    memory_budget_mib: u64,
    /// Worker threads [default: all cores].
    #[arg(long)]
    threads: Option<usize>,
    /// Output directory (summary.json, regions.csv, portals.obj, PNG slices).
    #[arg(long, short)]
    out: PathBuf,
    /// Print the JSON summary on standard output.
    #[arg(long)]
    json: bool,
}

fn parse_vec3(s: &str) -> std::result::Result<Vec3, String> {
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

/// The memory budget of `--memory-budget-mib`, checked against physical memory.
fn memory_budget(mib: u64) -> Result<u64> {
    lacuna::limits::check_memory_budget("--memory-budget-mib", mib.saturating_mul(1 << 20))
}

/// Refuses a scene with nothing to render (no triangles, no lights and no environment map:
/// random bytes or an image renamed `.obj`, an empty `{}` scene file) unless asked for.
fn check_not_empty(scene: &Scene, label: &str, allow_empty: bool) -> Result<()> {
    if allow_empty
        || scene.triangle_count() > 0
        || !scene.lights().is_empty()
        || scene.environment().is_some()
    {
        return Ok(());
    }
    Err(Error::invalid(format!(
        "scene {label} is empty (no triangles, lights or environment map): nothing to render; --allow-empty renders it anyway"
    )))
}

/// A scene ready to render with its settings: the scene file's, overridden by options.
struct Prepared {
    scene: Scene,
    camera: Camera,
    /// Render and integrator settings: defaults, the scene file's, then the flags.
    settings: ResolvedSettings,
    label: String,
    /// Bytes the film may take (`--memory-budget-mib`).
    memory_budget: u64,
}

fn load_builder(path: &Path) -> Result<(SceneBuilder, RenderSettingsFile, String)> {
    let (loaded, label) = load_scene_arg(path)?;
    for w in &loaded.warnings {
        eprintln!("lacuna: warning: {w}");
    }
    Ok((loaded.builder, loaded.settings, label))
}

/// Loads `--env` or adjusts the scene file's environment map with the `--env-*` options,
/// and builds the sampling structures `strategy` needs.
fn apply_environment(
    builder: &mut SceneBuilder,
    args: &SceneArgs,
    strategy: EnvStrategy,
) -> Result<()> {
    let mut map = match &args.env {
        Some(path) => {
            let budget = memory_budget(args.memory_budget_mib)?;
            let image = lacuna::light::environment::EnvImage::load_within(path, budget)?;
            let map = EnvironmentMap::new(image, EnvSettings::default())?;
            if map.image().clamped() > 0 {
                eprintln!(
                    "lacuna: warning: environment map {}: {} negative texel values clamped to 0",
                    path.display(),
                    map.image().clamped()
                );
            }
            map
        }
        None => match builder.environment() {
            Some(m) => (**m).clone(),
            None => {
                if args.env_scale.is_some()
                    || args.env_rotate.is_some()
                    || args.env_up.is_some()
                    || args.env_hidden
                    || args.env_layout.is_some()
                {
                    return Err(Error::invalid(
                        "--env-scale, --env-rotate, --env-up, --env-hidden and --env-layout need an environment map (--env FILE or the scene file's)",
                    ));
                }
                return Ok(());
            }
        },
    };
    if let Some(layout) = &args.env_layout {
        map = EnvironmentMap::new(convert_layout(map.image(), layout)?, *map.settings())?;
    }
    let mut settings = *map.settings();
    if let Some(s) = args.env_scale {
        settings.scale = s;
    }
    if let Some(r) = args.env_rotate {
        settings.rotate_degrees = r;
    }
    if let Some(u) = &args.env_up {
        settings.up = UpAxis::parse(u)?;
    }
    if args.env_hidden {
        settings.visible = false;
    }
    map.set_settings(settings)?;
    map.prepare(strategy);
    if args.verbose {
        let [ll, cube] = map.build_seconds();
        eprintln!(
            "environment: {}, {} clamped texel values, sampling structures built in {:.2} ms (lat-long) / {:.2} ms (cube), {:.1} MiB",
            lacuna::light::environment::describe(map.image().grid()),
            map.image().clamped(),
            ll * 1e3,
            cube * 1e3,
            mib(map.memory_bytes())
        );
    }
    builder.set_environment(Some(Arc::new(map)));
    Ok(())
}

/// What a command says about the sample budget (only `render` has both).
#[derive(Clone, Copy, Default)]
struct SampleBudget {
    spp: Option<u32>,
    time: Option<f64>,
}

/// Loads the scene and resolves its settings with the flags over the scene file's;
/// `integrator_spec` is the command's `--integrator`.
fn prepare(args: &SceneArgs, integrator_spec: Option<&str>, spp: SampleBudget) -> Result<Prepared> {
    let (mut builder, file, label) = match &args.scene {
        None => (
            two_rooms_builder()?,
            RenderSettingsFile::default(),
            "two-rooms".into(),
        ),
        Some(path) => load_builder(path)?,
    };
    let env = match &args.env_strategy {
        Some(s) => EnvStrategy::parse(s)?,
        None => EnvStrategy::default(),
    };
    let budget = memory_budget(args.memory_budget_mib)?;
    if let Some(n) = args.threads {
        if n == 0 {
            return Err(Error::invalid("--threads 0: at least 1 worker thread"));
        }
        lacuna::limits::check_threads("--threads", n)?;
    }
    if let Some(d) = args.max_depth {
        lacuna::limits::check_max_depth("--max-depth", d)?;
    }
    if let Some(n) = args.light_paths {
        lacuna::limits::check_light_paths("--light-paths", n as u64)?;
    }
    apply_environment(&mut builder, args, env)?;
    let scene = builder.build()?;
    check_not_empty(&scene, &label, args.allow_empty)?;
    let overrides = SettingsOverrides {
        integrator: integrator_spec.map(str::to_string),
        width: args.width,
        height: args.height,
        spp: spp.spp,
        time: spp.time,
        seed: args.seed,
        sampler: args
            .sampler
            .as_deref()
            .map(SamplerKind::parse)
            .transpose()?,
        threads: args.threads,
        max_depth: args.max_depth,
    };
    let mis = args.mis.as_deref().map(MisHeuristic::parse).transpose()?;
    let settings = resolve(&file, &overrides, |integrator| {
        integrator.mis = mis;
        integrator.light_paths = args.light_paths;
        integrator.env = env;
        if let Some(n) = args.env_samples {
            integrator.env_direct.light_samples = n;
        }
        if let Some(n) = args.env_bsdf_samples {
            integrator.env_direct.bsdf_samples = n;
        }
        skeleton_overrides(&mut integrator.skeleton, args)
    })?;
    lacuna::film::Film::check_budget(settings.render.width, settings.render.height, 0, budget)?;
    let (w, h) = (settings.render.width, settings.render.height);
    let mut camera = resolve_camera(&scene, None, w, h);
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
    if let Some(r) = args.lens_radius {
        if camera.lens_radius == 0.0 {
            // A new lens focuses on the target unless told otherwise.
            camera.focus_distance = (camera.target - camera.eye).length();
        }
        camera.lens_radius = r;
    }
    if let Some(f) = args.focus_distance {
        camera.focus_distance = f;
    }
    camera.validate()?;
    if args.verbose {
        let stats = scene.stats();
        let mem = scene.memory();
        eprintln!(
            "{label}: {} triangles ({} degenerate skipped), {} lights, BVH {} nodes built in {:.3} s",
            stats.triangles,
            stats.degenerate_triangles_skipped,
            scene.lights().len(),
            stats.bvh_nodes,
            stats.bvh_seconds
        );
        eprintln!(
            "memory: meshes {:.1} MiB, BVH {:.1} MiB, textures {:.1} MiB, lights {:.3} MiB, total {:.1} MiB",
            mib(mem.meshes),
            mib(mem.bvh),
            mib(mem.textures),
            mib(mem.lights),
            mib(mem.total())
        );
    }
    Ok(Prepared {
        scene,
        camera,
        settings,
        label,
        memory_budget: budget,
    })
}

/// The names of the registered integrators, for the help texts: read from
/// `integrator::REGISTRY`, so an integrator is listed as soon as it is registered.
fn integrator_names() -> String {
    let names: Vec<&str> = integrator::REGISTRY.iter().map(|r| r.name).collect();
    names.join(", ")
}

/// `render --integrator`'s help.
fn integrator_help() -> String {
    format!(
        "Integrator, one of {}, with options as NAME:KEY=VALUE:... (every integrator's keys: \
         docs/integrator-options.md) [default: path, or the scene file's]",
        integrator_names()
    )
}

/// `compare --integrators`'s help.
fn contenders_help() -> String {
    format!(
        "Comma-separated integrators, the first the baseline: any of {}, each with its own \
         options as NAME:KEY=VALUE:... (docs/integrator-options.md), which override the \
         command line's for that contender, and also sampler=sobol|independent \
         (e.g. path,path:rr_depth=3,path_skeleton or path:sampler=independent,path)",
        integrator_names()
    )
}

/// The `--c-skel`, `--skel-*` flags over the scene file's skeleton options. `--c-skel` and
/// `--skel-strength` are text (a number, `learned`, `auto:MAX`), parsed as the scene file's
/// and an integrator name's options are; the others are typed.
fn skeleton_overrides(skel: &mut SkeletonGuideSettings, args: &SceneArgs) -> Result<()> {
    if let Some(c) = &args.c_skel {
        skel.set("c_skel", c)?;
    }
    if let Some(s) = &args.skel_strength {
        skel.set("strength", s)?;
    }
    skel.update(|skel| {
        if let Some(n) = args.skel_resolution {
            skel.resolution = Resolution::LongestAxis(n);
        }
        if let Some(n) = args.skel_voxel_budget {
            skel.resolution = Resolution::VoxelBudget(n);
        }
        if let Some(n) = args.skel_light_rays {
            skel.light_rays = n;
        }
        if let Some(n) = args.skel_lobes {
            skel.max_lobes = n;
        }
        if args.skel_no_visibility {
            (skel.visibility_test, skel.voxel_visibility) = (false, false);
        }
    })
}

fn mib(bytes: usize) -> f64 {
    bytes as f64 / (1024.0 * 1024.0)
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
        let filled = (p.fraction.clamp(0.0, 1.0) * width as f64) as usize;
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

fn ensure_parent(path: &Path) -> Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    Ok(())
}

fn run_render(args: &RenderArgs) -> Result<()> {
    if !args.exposure.is_finite() {
        return Err(Error::invalid(format!(
            "--exposure {} must be a finite number of stops",
            args.exposure
        )));
    }
    let budget = SampleBudget {
        spp: args.spp,
        time: args.time,
    };
    let prep = prepare(&args.scene, args.integrator.as_deref(), budget)?;
    let name = prep.settings.integrator.clone();
    let mut integrator: Box<dyn integrator::Integrator> = if args.strategy.is_none()
        && args.strategy_images.is_none()
    {
        integrator::create(&name, prep.settings.integrator_settings)?
    } else {
        if name != "bdpt" {
            return Err(Error::invalid(
                "--strategy and --strategy-images need --integrator bdpt",
            ));
        }
        let integrator_settings = prep.settings.integrator_settings;
        let mut bdpt = match integrator_settings.light_paths {
            Some(n) => integrator::Bdpt::new(integrator_settings).with_light_paths(n as usize)?,
            None => integrator::Bdpt::new(integrator_settings),
        };
        if let Some(st) = &args.strategy {
            let parts: Vec<Option<u32>> = st.split(',').map(|p| p.trim().parse().ok()).collect();
            let [Some(s), Some(t)] = parts[..] else {
                return Err(Error::invalid(format!(
                    "--strategy '{st}' must be S,T (two integers)"
                )));
            };
            bdpt = bdpt.with_strategy(integrator::StrategyFilter {
                s,
                t,
                unweighted: args.unweighted,
            })?;
        }
        if args.strategy_images.is_some() {
            let max_len = integrator_settings.max_depth + 1;
            bdpt = bdpt.with_strategy_images(args.strategy_max_length.unwrap_or(max_len))?;
        }
        Box::new(bdpt)
    };
    // `--time`: a precomputation may stop early rather than spend the render's time.
    integrator.set_time_budget(prep.settings.render.time_limit.map(|t| t.as_secs_f64()));
    lacuna::film::Film::check_budget(
        prep.settings.render.width,
        prep.settings.render.height,
        integrator.layers().len(),
        prep.memory_budget,
    )?;
    let precomputation = prepare_integrator(integrator.as_mut(), &prep)?;
    let bar = ProgressBar::new(args.scene.quiet);
    let (film, stats) = render(
        &prep.scene,
        &prep.camera,
        integrator.as_ref(),
        &prep.settings.render,
        &|p| bar.update(p),
        &AtomicBool::new(false),
    )?;
    let meta = prep
        .settings
        .metadata(&prep.label, stats.spp, stats.seconds)
        .with(
            "precompute_seconds",
            format!("{:.3}", precomputation.seconds()),
        );
    write_film(&film, &args.out, args.exposure, &meta)?;
    write_alpha_preview(&film, &args.out)?;
    if let Some(dir) = &args.strategy_images {
        write_strategy_images(&film, dir, args.exposure, &meta)?;
    }
    if stats.largest_guided_ratio > 0.0 {
        println!(
            "{name}: largest guided path weight against path's for the same directions: {:.2}x",
            stats.largest_guided_ratio
        );
    }
    println!(
        "{}: {}x{}, {} spp of {} (max depth {}) in {:.2} s: {:.2} M samples/s, {:.2} M rays/s -> {}",
        prep.label,
        prep.settings.render.width,
        prep.settings.render.height,
        stats.spp,
        name,
        prep.settings.integrator_settings.max_depth,
        stats.seconds,
        stats.samples_per_second() / 1e6,
        stats.rays_per_second() / 1e6,
        args.out.display()
    );
    if let Some(bias) = integrator.bias() {
        println!("{}: {bias}", integrator.name());
    }
    for note in integrator.render_notes() {
        println!("{}: {note}", integrator.name());
    }
    Ok(())
}

/// `mis=auto`: the false-colour PNG of the `alpha` layer (thesis 001 Figure 5.7) beside the
/// output, as `NAME.alpha.png` (the layer itself is in the EXR).
fn write_alpha_preview(film: &Film, out: &Path) -> Result<()> {
    let Some(index) = film
        .layer_names()
        .iter()
        .position(|n| n == integrator::ALPHA_LAYER)
    else {
        return Ok(());
    };
    let colours: Vec<_> = film
        .layer(index)
        .iter()
        .map(|p| integrator::mis_auto::alpha_false_colour(p.x, p.y))
        .collect();
    let path = out.with_extension("alpha.png");
    lacuna::film::write_png_rgb(&path, film.width(), film.height(), &colours, 0.0)
}

/// Writes every strategy layer of `film` as EXR and PNG, and the weighted and unweighted
/// sheets: row k - 1 holds the strategies of paths of k segments, s = 0 on the left.
fn write_strategy_images(film: &Film, dir: &Path, exposure: f32, meta: &ExrMetadata) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let (w, h) = (film.width(), film.height());
    let mut cells = Vec::new();
    for (index, name) in film.layer_names().iter().enumerate() {
        let pixels = film.layer(index);
        lacuna::film::write_exr_rgb(&dir.join(format!("{name}.exr")), w, h, &pixels, meta)?;
        lacuna::film::write_png_rgb(&dir.join(format!("{name}.png")), w, h, &pixels, exposure)?;
        let (st, kind) = name.rsplit_once('_').expect("layer names are sS_tT_kind");
        let (s, t) = st
            .strip_prefix('s')
            .and_then(|r| r.split_once("_t"))
            .and_then(|(s, t)| Some((s.parse::<u32>().ok()?, t.parse::<u32>().ok()?)))
            .expect("layer names are sS_tT_kind");
        cells.push((kind.to_string(), s, s + t - 1, pixels));
    }
    let max_len = cells.iter().map(|c| c.2).max().unwrap_or(0);
    const GAP: u32 = 2;
    for kind in ["weighted", "unweighted"] {
        let (sw, sh) = ((max_len + 1) * (w + GAP), max_len * (h + GAP));
        let mut sheet = vec![lacuna::math::Rgb::ZERO; sw as usize * sh as usize];
        for (_, s, k, pixels) in cells.iter().filter(|c| c.0 == kind) {
            let (x0, y0) = (s * (w + GAP), (k - 1) * (h + GAP));
            for y in 0..h {
                for x in 0..w {
                    sheet[((y0 + y) * sw + x0 + x) as usize] = pixels[(y * w + x) as usize];
                }
            }
        }
        lacuna::film::write_png_rgb(&dir.join(format!("{kind}.png")), sw, sh, &sheet, exposure)?;
    }
    Ok(())
}

/// Runs the integrator's per-scene precomputation and prints its stages (nothing when there
/// is none).
fn prepare_integrator(
    integrator: &mut dyn integrator::Integrator,
    prep: &Prepared,
) -> Result<integrator::Precomputation> {
    let pre = lacuna::render::prepare(
        integrator,
        &prep.scene,
        &prep.camera,
        prep.settings.render.threads,
        &|_, _| true,
    )?;
    if !pre.stages.is_empty() {
        let stages: Vec<String> = pre
            .stages
            .iter()
            .map(|s| format!("{} {:.3} s", s.stage, s.seconds))
            .collect();
        println!(
            "{}: precomputation {:.3} s ({})",
            integrator.name(),
            pre.seconds(),
            stages.join(", ")
        );
        for note in &pre.notes {
            println!("{}: {note}", integrator.name());
        }
    }
    Ok(pre)
}

fn write_film(film: &Film, out: &Path, exposure: f32, meta: &ExrMetadata) -> Result<()> {
    ensure_parent(out)?;
    match out
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .as_deref()
    {
        Some("exr") => film.write_exr(out, meta),
        Some("png") => film.write_png(out, exposure),
        _ => Err(Error::invalid(format!(
            "output {} must end in .exr or .png",
            out.display()
        ))),
    }
}

fn run_reference(args: &ReferenceArgs) -> Result<()> {
    // A reference renders with `path` unless told otherwise, whatever the scene file names.
    let name = args.integrator.as_deref().unwrap_or(DEFAULT_INTEGRATOR);
    let budget = SampleBudget {
        spp: Some(args.spp),
        time: None,
    };
    let prep = prepare(&args.scene, Some(name), budget)?;
    let mut integrator = integrator::create(name, prep.settings.integrator_settings)?;
    prepare_integrator(integrator.as_mut(), &prep)?;
    let bar = ProgressBar::new(args.scene.quiet);
    let reference = render_reference(
        &prep.scene,
        &prep.camera,
        integrator.as_ref(),
        &prep.settings.render,
        &|p| bar.update(p),
    )?;
    let meta = prep
        .settings
        .metadata(&prep.label, reference.stats.spp, reference.stats.seconds)
        .with(
            "reference_mae_estimate",
            format!("{:e}", reference.noise.mae),
        )
        .with(
            "reference_rmse_estimate",
            format!("{:e}", reference.noise.rmse),
        )
        .with(
            "reference_rel_mse_estimate",
            format!("{:e}", reference.noise.rel_mse),
        );
    if args.out.extension().and_then(|e| e.to_str()) != Some("exr") {
        return Err(Error::invalid(format!(
            "reference output {} must be an .exr file",
            args.out.display()
        )));
    }
    write_film(&reference.film, &args.out, 0.0, &meta)?;
    println!(
        "{}: reference of {} spp ({}, max depth {}) in {:.1} s; estimated remaining error MAE {:.3e}, RMSE {:.3e}, relMSE {:.3e} -> {}",
        prep.label,
        reference.stats.spp,
        name,
        prep.settings.integrator_settings.max_depth,
        reference.stats.seconds,
        reference.noise.mae,
        reference.noise.rmse,
        reference.noise.rel_mse,
        args.out.display()
    );
    Ok(())
}

fn run_compare(args: &CompareArgs) -> Result<()> {
    if !(args.time > 0.0 && args.time.is_finite()) {
        return Err(Error::invalid(format!(
            "--time {} must be a positive number of seconds",
            args.time
        )));
    }
    // Refused now, not after rendering for the whole budget.
    if args.out.exists() && !args.out.is_dir() {
        return Err(Error::invalid(format!(
            "--out {} exists and is not a directory (compare writes a directory of reports)",
            args.out.display()
        )));
    }
    // Each contender renders for `--time`: the scene file's budget does not apply.
    let budget = SampleBudget::default();
    let mut prep = prepare(&args.scene, None, budget)?;
    prep.settings.render.time_limit = None;
    let reference = lacuna::film::read_exr_rgb_within(&args.reference, prep.memory_budget)?;
    if (reference.width, reference.height)
        != (prep.settings.render.width, prep.settings.render.height)
    {
        return Err(Error::invalid(format!(
            "reference {} is {}x{} but the render is {}x{}: give the same --width/--height",
            args.reference.display(),
            reference.width,
            reference.height,
            prep.settings.render.width,
            prep.settings.render.height
        )));
    }
    let noise = (|| {
        let get = |k: &str| reference.metadata.get(k)?.parse::<f64>().ok();
        Some(ImageErrors {
            mae: get("reference_mae_estimate")?,
            rmse: get("reference_rmse_estimate")?,
            rel_mse: get("reference_rel_mse_estimate")?,
        })
    })();
    let names: Vec<&str> = args
        .integrators
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .collect();
    let mut contenders = names
        .iter()
        .map(|n| Contender::from_spec(n, prep.settings.integrator_settings))
        .collect::<Result<Vec<_>>>()?;
    let (schedule, wall_per_second) = if args.concurrent {
        (Schedule::Concurrent, 1.0)
    } else {
        (Schedule::Sequential, names.len() as f64)
    };
    let runs = args
        .runs
        .unwrap_or(if args.time * wall_per_second * 3.0 <= 1800.0 {
            3
        } else {
            1
        });
    let bar = ProgressBar::new(args.scene.quiet);
    let cmp = compare_scheduled(
        &prep.scene,
        &prep.camera,
        &mut contenders,
        &reference.pixels,
        noise,
        &prep.settings.render,
        args.time,
        runs,
        schedule,
        &|p| bar.update(p),
    )?;
    write_report(
        &args.out,
        &cmp,
        &reference.pixels,
        prep.settings.render.width,
        prep.settings.render.height,
        &prep.label,
    )?;
    let summary = std::fs::read_to_string(args.out.join("summary.md"))
        .map_err(|e| Error::io(args.out.join("summary.md"), e))?;
    println!("{summary}");
    Ok(())
}

fn run_analyze(args: &AnalyzeArgs) -> Result<()> {
    use lacuna::analysis::{
        summary_json, write_analysis, write_skeleton, Analysis, AnalysisSettings, Outside,
        Resolution, Skeleton, SkeletonSettings,
    };
    let (builder, _, label) = match &args.scene {
        None => (
            two_rooms_builder()?,
            RenderSettingsFile::default(),
            "two-rooms".to_string(),
        ),
        Some(path) => load_builder(path)?,
    };
    let memory_budget = memory_budget(args.memory_budget_mib)?;
    if let Some(n) = args.threads {
        if n == 0 {
            return Err(Error::invalid("--threads 0: at least 1 worker thread"));
        }
        lacuna::limits::check_threads("--threads", n)?;
    }
    let scene = builder.build()?;
    check_not_empty(&scene, &label, false)?;
    let resolution = match (args.voxel_size, args.voxel_budget) {
        (Some(s), _) => Resolution::VoxelSize(s),
        (None, Some(b)) => Resolution::VoxelBudget(b),
        (None, None) => Resolution::LongestAxis(args.resolution),
    };
    let settings = AnalysisSettings {
        resolution,
        fill_interiors: args.fill_interiors,
        outside: if args.outside_empty {
            Outside::Empty
        } else {
            Outside::Solid
        },
        memory_budget,
        all_maps: args.all_maps || args.skeleton,
        // Without --all-maps the skeleton computes the Euclidean distance beside its thinning.
        euclidean: args.all_maps,
        ..Default::default()
    };
    let pool = lacuna::workers::WorkerPool::new(args.threads, None)?;
    let analysis = pool.install(|| Analysis::build(&scene, &settings, &|_, _| true))?;
    write_analysis(&args.out, &analysis)?;
    let skeleton = if args.skeleton {
        let settings = SkeletonSettings {
            parallel: !args.skeleton_sequential,
            topology: !args.no_topology,
        };
        let skeleton = pool.install(|| Skeleton::build(&analysis, &settings, &|_, _| true))?;
        let images = (!args.no_images).then_some(&scene);
        pool.install(|| write_skeleton(&args.out, images, &skeleton))?;
        Some(skeleton)
    } else {
        None
    };
    let mut summary: serde_json::Value = serde_json::from_str(&summary_json(&analysis))
        .map_err(|e| Error::invalid(format!("summary JSON: {e}")))?;
    let windows = if args.window_portals {
        let settings = lacuna::analysis::WindowPortalSettings::default();
        Some(pool.install(|| lacuna::analysis::window_portals(&scene, &settings))?)
    } else {
        None
    };
    if let Some(w) = &windows {
        pool.install(|| {
            lacuna::analysis::write_window_portal_image(&args.out, &scene, &w.portals)
        })?;
    }
    if let (Some(w), Some(obj)) = (&windows, summary.as_object_mut()) {
        let v = |a: lacuna::math::Vec3| serde_json::json!([a.x, a.y, a.z]);
        let list: Vec<serde_json::Value> = w
            .portals
            .iter()
            .map(|p| {
                serde_json::json!({
                    "corner": v(p.corner), "edge_u": v(p.edge_u), "edge_v": v(p.edge_v),
                    "outward": v(p.outward), "center": v(p.center()), "area": p.area(),
                })
            })
            .collect();
        obj.insert("window_portals".into(), serde_json::Value::Array(list));
        obj.insert(
            "window_portals_seconds".into(),
            serde_json::json!({ "analysis": w.analysis_seconds, "fit": w.fit_seconds, "voxel_size": w.voxel_size }),
        );
    }
    if skeleton.is_some() || windows.is_some() {
        if let Some(s) = &skeleton {
            if let (Some(obj), serde_json::Value::Object(extra)) =
                (summary.as_object_mut(), s.summary_json())
            {
                obj.extend(extra);
            }
        }
        std::fs::write(
            args.out.join("summary.json"),
            serde_json::to_string_pretty(&summary).expect("JSON of plain values"),
        )
        .map_err(|e| Error::io(args.out.join("summary.json"), e))?;
    }
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&summary).expect("JSON of plain values")
        );
    } else {
        let d = analysis.grid.dims;
        println!(
            "{label}: grid {}x{}x{} (voxel {:.4}), {} empty voxels, {} regions, {} portals in {:.3} s -> {}",
            d[0],
            d[1],
            d[2],
            analysis.grid.voxel_size,
            analysis.empty_voxels(),
            analysis.regions.len(),
            analysis.portals.len(),
            analysis.total_seconds(),
            args.out.display()
        );
        for t in &analysis.timings {
            println!("  {:<22} {:.4} s", t.stage, t.seconds);
        }
        if let Some(w) = &windows {
            println!(
                "window portals: {} (analysis {:.3} s at voxel {:.4}, fit {:.3} s)",
                w.portals.len(),
                w.analysis_seconds,
                w.voxel_size,
                w.fit_seconds
            );
            for p in &w.portals {
                let c = p.center();
                println!(
                    "  centre ({:.3}, {:.3}, {:.3}), {:.3} x {:.3}, outward ({}, {}, {})",
                    c.x,
                    c.y,
                    c.z,
                    p.edge_u.length(),
                    p.edge_v.length(),
                    p.outward.x,
                    p.outward.y,
                    p.outward.z
                );
            }
        }
        if let Some(s) = &skeleton {
            let f = &s.filtered.graph;
            println!(
                "skeleton: {} nodes, {} edges, {} components, cycle rank {}; filtered: {} nodes, {} edges in {:.3} s",
                s.raw.nodes.len(),
                s.raw.edges.len(),
                s.raw.components(),
                s.raw.cycle_rank(),
                f.nodes.len(),
                f.edges.len(),
                s.total_seconds()
            );
            if let Some(b) = s.empty_space {
                println!(
                    "empty space: b0 {} b1 {} b2 {} euler {} ({} diagonal-only contacts)",
                    b.b0, b.b1, b.b2, b.euler, s.diagonal_contacts
                );
            }
            for t in &s.timings {
                println!("  {:<30} {:.4} s", t.stage, t.seconds);
            }
        }
    }
    Ok(())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match &cli.command {
        Command::Render(args) => run_render(args),
        Command::Reference(args) => run_reference(args),
        Command::Compare(args) => run_compare(args),
        Command::Analyze(args) => run_analyze(args),
        Command::Family(args) => run_family(args),
        Command::CaptureLuminaire(args) => run_capture(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("lacuna: {e}");
            ExitCode::FAILURE
        }
    }
}
