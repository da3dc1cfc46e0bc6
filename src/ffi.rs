//! The one `#[cxx::bridge]`: plain shared structs and coarse functions over flat slices.
//! Every C++ call returns `Result`, so C++ exceptions arrive as Rust errors.

#[cxx::bridge(namespace = "binpick")]
pub(crate) mod bridge {
    /// PCL `pcl::Correspondence`: `query` indexes the source cloud, `matched` the target.
    #[derive(Clone, Copy, Debug, PartialEq)]
    struct Correspondence {
        query: u32,
        matched: u32,
        /// Squared distance (feature space for descriptor matches).
        distance: f32,
    }

    struct SacResult {
        kept: Vec<Correspondence>,
        /// Row-major 4x4, source -> target.
        transform: [f64; 16],
        rotation_det: f64,
        converged: bool,
    }

    struct Transform {
        /// Row-major 4x4.
        m: [f64; 16],
    }

    struct IcpParams {
        /// Row-major 4x4 initial guess, source -> target.
        initial: [f64; 16],
        max_correspondence_distance: f64,
        max_iterations: u32,
        transformation_epsilon: f64,
        /// Answer each iteration's nearest-neighbour queries in one FLANN call (same results
        /// as PCL's per-point search, several times faster).
        batch_correspondences: bool,
    }

    struct IcpResult {
        transform: [f64; 16],
        converged: bool,
        fitness: f64,
        iterations: u32,
        state: i32,
    }

    struct PlaneFit {
        found: bool,
        /// a, b, c, d of a x + b y + c z + d = 0 (unit normal).
        coefficients: [f32; 4],
        inliers: Vec<u32>,
    }

    struct Clusters {
        indices: Vec<u32>,
        offsets: Vec<u32>,
    }

    struct Features {
        values: Vec<f32>,
        valid: Vec<bool>,
    }

    unsafe extern "C++" {
        include!("binpick-pcl/cpp/include/binpick_pcl.h");

        /// A point cloud plus its kd-tree, owned by C++.
        type Cloud;

        fn set_pcl_verbosity(level: i32) -> Result<()>;
        fn upload_cloud(xyz: &[f32]) -> Result<UniquePtr<Cloud>>;
        fn cloud_len(cloud: &Cloud) -> usize;
        fn nearest_sq_distances(cloud: &Cloud, query_xyz: &[f32]) -> Result<Vec<f32>>;

        fn uniform_sampling(xyz: &[f32], leaf: f32) -> Result<Vec<u32>>;
        fn voxel_grid(xyz: &[f32], leaf: f32) -> Result<Vec<f32>>;

        fn estimate_normals(
            xyz: &[f32],
            radius: f32,
            viewpoint: &[f32],
            threads: u32,
        ) -> Result<Vec<f32>>;
        fn cloud_fpfh(
            surface: &Cloud,
            keypoints: &[u32],
            feature_radius: f32,
            normal_radius: f32,
            viewpoint: &[f32],
            threads: u32,
        ) -> Result<Features>;

        fn euclidean_clusters(
            cloud: &Cloud,
            tolerance: f32,
            min_size: u32,
            max_size: u32,
        ) -> Result<Clusters>;
        fn segment_plane(
            xyz: &[f32],
            distance_threshold: f32,
            max_iterations: u32,
        ) -> Result<PlaneFit>;

        fn match_features(
            source_features: &[f32],
            target_features: &[f32],
        ) -> Result<Vec<Correspondence>>;
        fn reject_sample_consensus(
            source_xyz: &[f32],
            target_xyz: &[f32],
            correspondences: &[Correspondence],
            inlier_threshold: f32,
            max_iterations: u32,
        ) -> Result<SacResult>;
        fn estimate_svd(
            source_xyz: &[f32],
            target_xyz: &[f32],
            correspondences: &[Correspondence],
        ) -> Result<Transform>;
        fn icp_align(target: &Cloud, source_xyz: &[f32], params: &IcpParams) -> Result<IcpResult>;
    }
}

// SAFETY: `Cloud` is immutable after construction (points + kd-tree built in `upload_cloud`)
// and every C++ function takes it by const reference; FLANN searches are const and keep no
// shared mutable state, so it may be sent to and shared between threads.
unsafe impl Send for bridge::Cloud {}
unsafe impl Sync for bridge::Cloud {}
