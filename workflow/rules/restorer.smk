# Restoration pairs (renders of the original trajectory from under-trained snapshots, paired with
# the ground truth; paper Fig. 3), the DriveRestorer fine-tuning of each restorer backbone and its
# optional pixel refiner.


rule make_pairs_segment:
    input:
        scene=results("scenes", "{segment}"),
        runs=lambda wildcards: [run_model(wildcards.segment, f"baseline-{b}") for b in config["restorer"]["pair_segment_backbones"]],
    output:
        directory(results("pairs", "segments", "{segment}")),
    params:
        runs=lambda wildcards, input: " ".join(os.path.dirname(path) for path in input.runs),
        stages=config["restorer"]["pair_stages"],
    threads: config["threads"]["restorer"]
    priority: RESTORER_PATH_PRIORITY
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("make_pairs_segment", "{segment}"),
    benchmark:
        benchmark_file("make_pairs_segment", "{segment}")
    shell:
        "recondreamer make-pairs --run {params.runs} --scene {input.scene} --out {output} "
        "--stages {params.stages} --threads {threads} > {log} 2>&1"


rule make_pairs_corpus:
    input:
        scene=results("corpus", "{corpus_scene}"),
        runs=lambda wildcards: [results("corpus_runs", wildcards.corpus_scene, b, "model.pt") for b in config["restorer"]["pair_corpus_backbones"]],
    output:
        directory(results("pairs", "corpus", "{corpus_scene}")),
    params:
        runs=lambda wildcards, input: " ".join(os.path.dirname(path) for path in input.runs),
        stages=config["restorer"]["pair_stages"],
    threads: config["threads"]["restorer"]
    priority: RESTORER_PATH_PRIORITY
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("make_pairs_corpus", "{corpus_scene}"),
    benchmark:
        benchmark_file("make_pairs_corpus", "{corpus_scene}")
    shell:
        "recondreamer make-pairs --run {params.runs} --scene {input.scene} --out {output} "
        "--stages {params.stages} --threads {threads} > {log} 2>&1"


rule make_cycle_pairs_corpus:
    # Cycle pairs (docs/foundation.md): the corpus scene's Street Gaussians run renders a lateral drive,
    # a second run (cycle_runs/, resumed after a kill) trains on those renders alone and renders the
    # recorded trajectory, paired with the recorded frames.
    input:
        scene=results("corpus", "{corpus_scene}"),
        model=results("corpus_runs", "{corpus_scene}", CYCLE_BACKBONE, "model.pt"),
    output:
        directory(results("pairs", "cycle", "{corpus_scene}", "{cycle_trajectory}")),
    params:
        run=lambda wildcards, input: parent(input.model),
        cycle_run=lambda wildcards: results("cycle_runs", wildcards.corpus_scene, wildcards.cycle_trajectory),
        options=RECON_OPTIONS,
    threads: config["threads"]["recon"]
    priority: RESTORER_PATH_PRIORITY
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("make_cycle_pairs_corpus", "{corpus_scene}/{cycle_trajectory}"),
    benchmark:
        benchmark_file("make_cycle_pairs_corpus", "{corpus_scene}/{cycle_trajectory}")
    shell:
        "recondreamer make-cycle-pairs --run {params.run} --scene {input.scene} --trajectory {wildcards.cycle_trajectory} "
        "--cycle-run {params.cycle_run} --out {output} {params.options} --threads {threads} > {log} 2>&1"


rule train_restorer:
    input:
        world_model=lambda wildcards: results("models", f"world_model_{WORLD_MODEL_OF[wildcards.restorer]}.pt"),
        pairs=pair_dirs(),
    output:
        results("models", "restorer_{restorer}.pt"),
    params:
        steps=option("--steps", config["restorer"]["steps"]),
        crop=option("--crop", None if config["restorer"]["crop"] is None else " ".join(map(str, config["restorer"]["crop"]))),
        options=" ".join(
            option(flag, config["restorer"][key])
            for flag, key in (
                ("--batch-size", "batch_size"),
                ("--window", "window"),
                ("--timestep-power", "timestep_power"),
                ("--pixel-loss-weight", "pixel_loss_weight"),
                ("--ema-decay", "ema_decay"),
                ("--blocks-per-level", "blocks_per_level"),
                ("--seed", "seed"),
            )
        )
        + RESTORER_DEVICE,
        mask=lambda wildcards: option("--mask-probability", config["restorer"]["mask_probability"]) if wildcards.restorer == "dd2_mask" else "",
    threads: config["threads"]["restorer"]
    priority: RESTORER_PATH_PRIORITY
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("train_restorer", "{restorer}"),
    benchmark:
        benchmark_file("train_restorer", "{restorer}")
    shell:
        "recondreamer train-restorer --arch {wildcards.restorer} --world-model {input.world_model} "
        "--pairs {input.pairs} --out {output} {params.steps} {params.crop} {params.options} {params.mask} --threads {threads} > {log} 2>&1"


rule train_refiner:
    input:
        restorer=results("models", "restorer_{restorer}.pt"),
        pairs=pair_dirs(),
    output:
        results("models", "restorer_{restorer}_refined.pt"),
    params:
        options=" ".join(
            (
                option("--steps", config["restorer"]["refiner_steps"]),
                option("--temporal-neighbours", config["restorer"]["refiner_neighbours"]),
                option("--seed", config["restorer"]["seed"]),
            )
        )
        + RESTORER_DEVICE,
    threads: config["threads"]["restorer"]
    priority: RESTORER_PATH_PRIORITY
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("train_refiner", "{restorer}"),
    benchmark:
        benchmark_file("train_refiner", "{restorer}")
    shell:
        "recondreamer train-refiner --restorer {input.restorer} --pairs {input.pairs} --out {output} {params.options} "
        "--threads {threads} > {log} 2>&1"
