//! `hytrace info`: what a scene holds and what its acceleration structures cost.

use anyhow::Result;
use hytrace::trace::SceneTracer;
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `hytrace info`.
#[derive(clap::Parser)]
pub struct InfoArgs {
    /// Mesh BVH build quality (overrides the scene's `tracer.bvh`).
    #[arg(long, value_enum)]
    pub bvh: Option<super::flags::BvhArg>,
    /// Scene file (.ron) or mesh file (.gltf, .glb, .obj, .ply); omit for the showcase.
    pub scene: Option<PathBuf>,
}

/// Prints the summary.
pub fn run(args: InfoArgs) -> Result<()> {
    let start = Instant::now();
    let mut scene = super::load_any(args.scene.as_deref(), None)?;
    if let Some(q) = args.bvh {
        scene.tracer.bvh = q.into();
    }
    let load = start.elapsed();
    let m = &scene.meshes;
    println!("scene        {}", scene.source_name);
    println!("load time    {:.3} s", load.as_secs_f64());
    println!(
        "meshes       {} ({} unique triangles, {} vertices)",
        m.meshes.len(),
        m.unique_triangle_count(),
        m.meshes.iter().map(|x| x.positions.len()).sum::<usize>()
    );
    println!(
        "instances    {} ({} triangles placed)",
        m.instances.len(),
        m.triangle_count()
    );
    println!(
        "materials    {} ({} from mesh files), {} textures",
        scene.materials.len(),
        m.materials.len(),
        m.textures.len()
    );
    let nodes: usize = scene.objects.iter().map(|o| o.node.node_count()).sum();
    let instrs: usize = scene.objects.iter().map(|o| o.lowered.distance.len()).sum();
    let unbounded = scene
        .objects
        .iter()
        .filter(|o| !o.bounds().is_finite())
        .count();
    // an object split into parts is one object of the file, traced as several
    let traced = if scene.objects.len() == scene.sdf_object_count() {
        String::new()
    } else {
        format!(
            "; traced as {} objects, unions split into their members",
            scene.objects.len()
        )
    };
    println!(
        "SDF objects  {} ({} nodes, {} tape instructions, {} unbounded{traced})",
        scene.sdf_object_count(),
        nodes,
        instrs,
        unbounded
    );
    println!("lights       {}", scene.lights.len());
    let b = scene.finite_bounds().union(&m.bounds());
    if b.is_empty() {
        println!("bounds       (nothing finite)");
    } else {
        let v = |p: glam::Vec3| p.to_array().map(|x| super::readable(x, 4)).join(", ");
        println!("bounds       ({}) .. ({})", v(b.min), v(b.max));
    }
    let build = Instant::now();
    let tracer = SceneTracer::new(&scene);
    let total = build.elapsed();
    let mesh = tracer.mesh_accel();
    println!(
        "mesh BVH     {:?} quality: {} BLAS with {} nodes (deepest {} levels), TLAS {} nodes ({} levels), built in {:.3} s",
        scene.tracer.bvh,
        mesh.blas.iter().filter(|b| !b.is_empty()).count(),
        mesh.blas.iter().map(|b| b.node_count()).sum::<usize>(),
        mesh.blas
            .iter()
            .map(|b| b.stats().max_depth)
            .max()
            .unwrap_or(0),
        mesh.tlas.node_count(),
        mesh.tlas.stats().max_depth,
        mesh.build_time.as_secs_f64()
    );
    if let Some((_, origin)) = mesh.tlas.merged() {
        let mut instances: Vec<u32> = origin.iter().map(|o| o.0).collect();
        instances.dedup();
        println!(
            "merged       {} instances of meshes placed once ({} triangles) traced as one tree in world space",
            instances.len(),
            origin.len()
        );
    }
    println!(
        "SDF BVH      {} nodes; all structures built in {:.3} s",
        tracer.sdf_accel().node_count(),
        total.as_secs_f64()
    );
    print_fields(&scene, &tracer);
    for w in &m.warnings {
        println!("warning      {w}");
    }
    Ok(())
}

/// Most objects listed one by one; the rest only count in the total.
const LISTED_OBJECTS: usize = 12;

/// One line per SDF object (up to [`LISTED_OBJECTS`]) about its octree of specialised tapes,
/// then the totals.
fn print_fields(scene: &hytrace::scene::Scene, tracer: &SceneTracer) {
    use hytrace::accel::field::OctreeStats;
    let mut total = OctreeStats::default();
    let mut trees = 0;
    for (i, (object, field)) in scene.objects.iter().zip(tracer.fields()).enumerate() {
        let whole = field.whole.len();
        let Some(tree) = &field.octree else {
            if i < LISTED_OBJECTS {
                println!("SDF octree   {}: none (whole tape of {whole})", object.name);
            }
            continue;
        };
        let st = tree.stats();
        trees += 1;
        total.nodes += st.nodes;
        total.leaves += st.leaves;
        total.empty += st.empty;
        total.full += st.full;
        total.tapes += st.tapes;
        total.instructions += st.instructions;
        total.bytes += st.bytes;
        total.native_bytes += st.native_bytes;
        if i < LISTED_OBJECTS {
            println!(
                "SDF octree   {}: {} nodes, {} leaves ({} empty, {} full, {} crossed), {} tapes, \
                 crossed leaves' tapes {:.1} of {whole} instructions on average (sphere tracing \
                 {}), {:.1} KiB, native code {:.1} KiB",
                object.label(),
                st.nodes,
                st.leaves,
                st.empty,
                st.full,
                st.leaves - st.empty - st.full,
                st.tapes,
                st.mean_surface_tape,
                if tree.marched_whole() {
                    "takes the whole tape"
                } else {
                    "walks the leaves"
                },
                st.bytes as f64 / 1024.0,
                st.native_bytes as f64 / 1024.0
            );
        }
    }
    if scene.objects.len() > LISTED_OBJECTS {
        println!(
            "SDF octree   … {} more objects",
            scene.objects.len() - LISTED_OBJECTS
        );
    }
    if trees > 0 {
        println!(
            "SDF octrees  {trees}: {} nodes, {} tapes, {} instructions, {:.2} MiB, native code \
             {:.2} MiB, built in {:.3} s (at most {} nodes, {} instructions and {} MiB of native \
             code per object)",
            total.nodes,
            total.tapes,
            total.instructions,
            total.bytes as f64 / (1024.0 * 1024.0),
            total.native_bytes as f64 / (1024.0 * 1024.0),
            tracer.field_build_time().as_secs_f64(),
            hytrace::accel::field::MAX_NODES,
            hytrace::accel::field::MAX_INSTRUCTIONS,
            hytrace::accel::field::NATIVE_CODE_BYTES >> 20
        );
    }
}
