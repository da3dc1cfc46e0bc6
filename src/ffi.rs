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
        /// Also stop when the mean squared correspondence distance changes by less than this
        /// fraction between iterations (PCL's Euclidean fitness epsilon); 0 = off.
        relative_mse: f64,
        /// Keep only mutual nearest neighbours (PCL's `setUseReciprocalCorrespondences`).
        reciprocal: bool,
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

    // --- Reference pipeline (cpp/reference/): thesis Algorithms 1 and 2 written directly in
    // C++ against PCL, one call per scene. Lengths in the cloud's units (binpick: mm).

    /// Parameters of the reference pipeline (binpick's `Params`, flattened).
    #[cfg(feature = "reference")]
    #[derive(Clone, Debug)]
    struct ReferenceParams {
        /// 1 = separated FPFH (thesis 4.1), 2 = merged FPFH (4.2).
        algorithm: u8,
        resolution: f64,
        roi_enabled: bool,
        roi_min: [f64; 3],
        roi_max: [f64; 3],
        support_enabled: bool,
        support_distance: f64,
        support_max_planes: u32,
        support_min_points_factor: f64,
        support_ransac_iterations: u32,
        cluster_tolerance_factor: f64,
        cluster_min_factor: f64,
        cluster_max_factor: f64,
        initial_leaf: f64,
        fpfh_radii: Vec<f64>,
        normal_radius_factor: f64,
        /// FPFH search surface: false = the keypoints themselves, true = the full cloud.
        feature_surface_cloud: bool,
        sac_thresholds: Vec<f64>,
        sac_iterations: u32,
        initial_score_max: f64,
        final_leaf: f64,
        icp_iterations: u32,
        icp_transformation_epsilon: f64,
        icp_max_correspondence: f64,
        outlier_distance: f64,
        final_score_max: f64,
        scene_viewpoint: [f64; 3],
        model_viewpoint: [f64; 3],
        /// Threads of the OpenMP loop over clusters (0 = OpenMP's default).
        threads: u32,
    }

    /// How the reference pipeline's ICP ended for one detection.
    #[cfg(feature = "reference")]
    #[repr(u8)]
    #[derive(Debug)]
    enum IcpFailure {
        /// ICP ran and returned a proper rotation.
        None = 0,
        /// PCL threw (`icp_error`).
        Pcl = 1,
        /// PCL's transform is not a proper rotation (`icp_det`).
        ImproperRotation = 2,
    }

    /// Why the reference pipeline's search in one cluster stopped (thesis 4.1 steps 1-4).
    #[cfg(feature = "reference")]
    #[repr(u8)]
    #[derive(Debug)]
    enum ClusterOutcome {
        NoConsensus = 0,
        /// Step 2: the best initial alignment's Euclidean score is too high.
        InitialRejected = 1,
        /// Step 4: the final alignment's percent of outliers is too high.
        FinalRejected = 2,
        Accepted = 3,
    }

    /// One accepted detection of the reference pipeline.
    #[cfg(feature = "reference")]
    #[derive(Clone, Debug)]
    struct ReferenceDetection {
        /// Row-major 4x4, model -> scene (final pose).
        pose: [f64; 16],
        initial_pose: [f64; 16],
        initial_score: f64,
        final_score: f64,
        score_before_icp: f64,
        cluster: u32,
        /// Index into `fpfh_radii` of the winning radius; -1 for Algorithm 2.
        fpfh_radius_index: i32,
        sac_threshold: f64,
        sac_inliers: u32,
        icp_converged: bool,
        icp_iterations: u32,
        /// PCL's fitness score (may be non-finite or huge when ICP matched nothing).
        icp_fitness: f64,
        icp_adopted: bool,
        icp_failure: IcpFailure,
        icp_error: String,
        icp_det: f64,
    }

    /// What happened in one cluster.
    #[cfg(feature = "reference")]
    #[derive(Clone, Debug)]
    struct ReferenceCluster {
        points: u32,
        outcome: ClusterOutcome,
        /// The rejected score for `InitialRejected` and `FinalRejected`.
        score: f64,
    }

    #[cfg(feature = "reference")]
    #[derive(Clone, Debug)]
    struct ReferencePlane {
        coefficients: [f32; 4],
        points: u32,
    }

    /// Wall-clock milliseconds. Per-cluster stages add up the work of all OpenMP threads.
    #[cfg(feature = "reference")]
    #[derive(Clone, Debug)]
    struct ReferenceTimings {
        /// Up-front model checks (voxel grid, keypoints, FPFH validity, final keypoints).
        model_preparation_ms: f64,
        preprocess_ms: f64,
        /// Euclidean clustering plus the scene's final keypoints.
        clustering_ms: f64,
        initial_alignment_ms: f64,
        final_alignment_ms: f64,
        /// The whole call.
        total_ms: f64,
        /// Stage breakdown inside the cluster loop (thesis 5.7 pie charts).
        model_features_ms: f64,
        cluster_keypoints_ms: f64,
        cluster_fpfh_ms: f64,
        correspondences_ms: f64,
        rejection_ms: f64,
        svd_ms: f64,
        euclidean_score_ms: f64,
        icp_ms: f64,
        outlier_score_ms: f64,
        /// OpenMP threads of the cluster loop and the runtime's max active levels.
        omp_threads: u32,
        omp_max_active_levels: i32,
    }

    #[cfg(feature = "reference")]
    #[derive(Clone, Debug)]
    struct ReferenceResult {
        /// In cluster order (not ranked).
        detections: Vec<ReferenceDetection>,
        clusters: Vec<ReferenceCluster>,
        input_points: u64,
        outside_roi: u64,
        voxel_merged: u64,
        support_planes: Vec<ReferencePlane>,
        remaining: u64,
        /// Flat xyz of the model's final keypoints (for the pick height).
        model_final_keypoints: Vec<f32>,
        timings: ReferenceTimings,
    }

    extern "Rust" {
        /// Whether the Rust caller asked the running call to stop (`crate::set_interrupt` on
        /// this thread); long C++ loops poll it between chunks (`check_interrupt`).
        fn interrupt_requested() -> bool;
    }

    unsafe extern "C++" {
        include!("binpick-pcl/cpp/include/binpick_pcl.h");

        /// A point cloud plus its kd-tree, owned by C++.
        type Cloud;

        fn set_pcl_verbosity(level: i32) -> Result<()>;
        fn upload_cloud(xyz: &[f32]) -> Result<UniquePtr<Cloud>>;
        fn upload_cloud_with_neighbourhoods(
            xyz: &[f32],
            radius: f32,
            threads: u32,
        ) -> Result<UniquePtr<Cloud>>;
        fn cloud_len(cloud: &Cloud) -> usize;
        fn cloud_neighbourhood_radius(cloud: &Cloud) -> f64;
        fn nearest_sq_distances(cloud: &Cloud, query_xyz: &[f32]) -> Result<Vec<f32>>;

        fn uniform_sampling(xyz: &[f32], leaf: f32) -> Result<Vec<u32>>;
        fn voxel_grid(xyz: &[f32], leaf: f32) -> Result<Vec<f32>>;

        fn estimate_normals(
            xyz: &[f32],
            radius: f32,
            viewpoint: &[f32],
            threads: u32,
        ) -> Result<Vec<f32>>;
        fn estimate_normals_at(
            xyz: &[f32],
            at: &[u32],
            radius: f32,
            viewpoint: &[f32],
            threads: u32,
        ) -> Result<Vec<f32>>;
        fn cloud_normals_at(
            cloud: &Cloud,
            at: &[u32],
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
            threads: u32,
        ) -> Result<PlaneFit>;
        fn segment_plane_pcl(
            xyz: &[f32],
            distance_threshold: f32,
            max_iterations: u32,
        ) -> Result<PlaneFit>;
        fn plane_inlier_counts(
            xyz: &[f32],
            planes: &[f32],
            distance_threshold: f64,
        ) -> Result<Vec<u64>>;

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
        fn reject_sample_consensus_sweep(
            source_xyz: &[f32],
            target_xyz: &[f32],
            correspondences: &[Correspondence],
            inlier_thresholds: &[f32],
            max_iterations: u32,
        ) -> Result<Vec<SacResult>>;
        fn estimate_svd(
            source_xyz: &[f32],
            target_xyz: &[f32],
            correspondences: &[Correspondence],
        ) -> Result<Transform>;
        fn icp_align(target: &Cloud, source_xyz: &[f32], params: &IcpParams) -> Result<IcpResult>;

        #[cfg(feature = "reference")]
        fn reference_recognize(
            model_xyz: &[f32],
            scene_xyz: &[f32],
            params: &ReferenceParams,
        ) -> Result<ReferenceResult>;
    }
}

fn interrupt_requested() -> bool {
    crate::interrupt_requested()
}

// SAFETY: `Cloud` is immutable after construction (points + kd-tree built in `upload_cloud`)
// and every C++ function takes it by const reference; FLANN searches are const and keep no
// shared mutable state, so it may be sent to and shared between threads.
unsafe impl Send for bridge::Cloud {}
unsafe impl Sync for bridge::Cloud {}
