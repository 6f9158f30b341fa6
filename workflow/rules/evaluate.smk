# Metrics of every run (NTA-IoU, NTL-IoU, FID; PSNR/SSIM against the true novel views of synthetic
# scenes), the preference judge of table 3 and the study page for people.

EVAL_OVERRIDES = " ".join(
    option(flag, config["eval_models"][key]) for flag, key in (("--detector", "detector"), ("--lane-model", "lane_model"), ("--fid-model", "fid_model"))
)


rule evaluate:
    # Renders the run along every trajectory, then scores the renders, in one process: torch starts
    # once per run instead of twice (144 runs in the default DAG). The renders stay for the
    # qualitative grids, the judge and the study page.
    input:
        model=lambda wildcards: run_model(wildcards.segment, wildcards.run),
        scene=results("scenes", "{segment}"),
        models=eval_model_files(),
    output:
        renders=[directory(path) for path in render_dirs("{segment}", "{run}")],
        metrics=results("metrics", "{segment}", "{run}.json"),
        features=results("metrics", "{segment}", "{run}.features.npz"),
    params:
        run=lambda wildcards, input: parent(input.model),
        renders=lambda wildcards, output: " ".join(f"--renders {d} --trajectory {t}" for d, t in zip(output.renders, TRAJECTORIES)),
        models=lambda wildcards, input: option("--models", parent(input.models[0]) if input.models else None),
        overrides=EVAL_OVERRIDES,
        device=option("--device", config["recon"]["device"]),  # where the run is rendered
        min_lidar_points=config["evaluation"]["min_lidar_points"],
        score_threshold=config["evaluation"]["score_threshold"],
    threads: config["threads"]["evaluate"]
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("evaluate", "{segment}/{run}"),
    benchmark:
        benchmark_file("evaluate", "{segment}/{run}")
    shell:
        "recondreamer evaluate --scene {input.scene} --run {params.run} {params.device} {params.renders} {params.models} {params.overrides} "
        "--min-lidar-points {params.min_lidar_points} --score-threshold {params.score_threshold} "
        "--out {output.metrics} --features-out {output.features} --threads {threads} > {log} 2>&1"


rule judge:
    input:
        scenes=[scene_dir(s) for s in SEGMENTS],
        renders=preference_render_dirs(),
    output:
        results("preference", "judge.json"),
    params:
        clips=" ".join(
            f"--clip {scene_dir(s)} {t} {PLAN.preference_method().run_id}={a} {versus}={b}"
            for s, t, a, versus, b in preference_pairs()
        ),
        metric=config["preference"]["metric"],
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("judge", "all"),
    benchmark:
        benchmark_file("judge", "all")
    shell:
        "recondreamer judge {params.clips} --metric {params.metric} --out {output} > {log} 2>&1"


rule study_page:
    input:
        preference_render_dirs(),
    output:
        # Not tagged for the report: a directory (page + media) only fits a zip report, and
        # 'snakemake --report results/report.html' must work; workflow.rst points to it.
        directory(results("study")),
    params:
        clips=" ".join(
            f"--clip {s} {t} {PLAN.preference_method().run_id}={a} {versus}={b}" for s, t, a, versus, b in preference_pairs()
        ),
        seed=config["preference"]["study_seed"],
        fps=config["preference"]["study_fps"],
        media=config["preference"]["study_format"],
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("study_page", "all"),
    benchmark:
        benchmark_file("study_page", "all")
    shell:
        "recondreamer study-page {params.clips} --out {output} --seed {params.seed} --fps {params.fps} "
        "--format {params.media} > {log} 2>&1"


rule study_ingest:
    input:
        answers=config["preference"]["answers"],
        study=results("study"),
    output:
        results("preference", "people.json"),
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("study_ingest", "all"),
    benchmark:
        benchmark_file("study_ingest", "all")
    shell:
        "recondreamer study-ingest {input.answers} --placement {input.study}/placement.json --out {output} > {log} 2>&1"
