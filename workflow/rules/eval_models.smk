# Evaluation models (vehicle detector, lane segmenter, FID features) trained on the corpus only.


rule train_eval_models:
    input:
        corpus_scene_dirs(),
    output:
        detector=results("eval_models", "vehicle_detector.pt"),
        lanes=results("eval_models", "lane_segmenter.pt"),
        features=results("eval_models", "fid_features.pt"),
        metrics=results("eval_models", "metrics.json"),
    params:
        corpus=lambda wildcards, input: parent(input[0]),
        out=lambda wildcards, output: parent(output.metrics),
        settings=" ".join(
            f"--{key.replace('_', '-')} {config['eval_models'][key]}"
            for key in ("detector_steps", "detector_upsample", "lane_steps", "feature_steps", "batch_size", "frame_stride", "holdout_scenes", "seed")
        ),
        min_lidar_points=config["evaluation"]["min_lidar_points"],
    threads: config["threads"]["evaluate"]
    priority: FEEDER_PRIORITY
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("train_eval_models", "all"),
    benchmark:
        benchmark_file("train_eval_models", "all")
    shell:
        "recondreamer train-eval-models --corpus {params.corpus} --out {params.out} {params.settings} "
        "--min-lidar-points {params.min_lidar_points} --threads {threads} > {log} 2>&1"
