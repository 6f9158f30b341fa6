# The foundation target (config/foundation.yaml): gate scenes no model saw, their Street Gaussians
# reconstructions and pairs, the gates of every foundation model, and the weight set with its
# manifest. The models themselves are the ordinary training rules (pretrain.smk, restorer.smk,
# eval_models.smk) on the corpus.

GATE_SCENES = [f"gate-{i:03d}" for i in range(len(FOUNDATION["gate_seeds"]))]
GATE_BACKBONE = "street"  # the gates restore Street Gaussians renders, as the paper's main tables
GATE_TRAJECTORIES = ["original", "shift@3", "shift@6"]


wildcard_constraints:
    gate_scene=r"gate-\d+",


rule synth_gate_scene:
    output:
        directory(results("gate_scenes", "{gate_scene}")),
    params:
        seed=lambda wildcards: FOUNDATION["gate_seeds"][GATE_SCENES.index(wildcards.gate_scene)],
        preset=config["synthetic"]["corpus"]["preset"],
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("synth_gate_scene", "{gate_scene}"),
    benchmark:
        benchmark_file("synth_gate_scene", "{gate_scene}")
    shell:
        "recondreamer synth --seed {params.seed} --preset {params.preset} --scene-id {wildcards.gate_scene} "
        "--out {output} > {log} 2>&1"


rule train_gate_recon:
    input:
        scene=results("gate_scenes", "{gate_scene}"),
    output:
        results("gate_runs", "{gate_scene}", GATE_BACKBONE, "model.pt"),
    params:
        run=lambda wildcards, output: parent(output[0]),
        options=RECON_OPTIONS,
    threads: config["threads"]["recon"]
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("train_gate_recon", "{gate_scene}"),
    benchmark:
        benchmark_file("train_gate_recon", "{gate_scene}")
    shell:
        f"recondreamer train-recon --scene {{input.scene}} --model {GATE_BACKBONE} --out {{params.run}} "
        "{params.options} --threads {threads} > {log} 2>&1"


rule make_gate_pairs:
    # Original-trajectory pairs of under-trained snapshots, and the final model's renders along the
    # novel trajectories with their true novel views (scored by the gates only, never trained on).
    input:
        scene=results("gate_scenes", "{gate_scene}"),
        model=results("gate_runs", "{gate_scene}", GATE_BACKBONE, "model.pt"),
    output:
        directory(results("gate_pairs", "{gate_scene}")),
    params:
        run=lambda wildcards, input: parent(input.model),
        stages=config["restorer"]["pair_stages"],
        trajectories=" ".join(GATE_TRAJECTORIES),
    threads: config["threads"]["restorer"]
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("make_gate_pairs", "{gate_scene}"),
    benchmark:
        benchmark_file("make_gate_pairs", "{gate_scene}")
    shell:
        "recondreamer make-pairs --run {params.run} --scene {input.scene} --out {output} --stages {params.stages} "
        "--trajectories {params.trajectories} --threads {threads} > {log} 2>&1"


rule foundation_gates:
    input:
        restorers=[results("models", f"restorer_{arch}.pt") for arch in FOUNDATION_RESTORERS],
        autoencoder=results("models", "autoencoder.pt"),
        eval_metrics=results("eval_models", "metrics.json"),
        detector=results("eval_models", "vehicle_detector.pt"),
        lanes=results("eval_models", "lane_segmenter.pt"),
        pairs=[results("gate_pairs", s) for s in GATE_SCENES],
        scenes=[results("gate_scenes", s) for s in GATE_SCENES],
    output:
        gates=results("foundation", "gates.json"),
        report=results("foundation", "GATES.md"),
    params:
        restorers=lambda wildcards, input: " ".join(f"{arch}={path}" for arch, path in zip(FOUNDATION_RESTORERS, input.restorers)),
        gate_seeds=" ".join(str(seed) for seed in FOUNDATION["gate_seeds"]),
        corpus_seeds=f"{config['synthetic']['corpus']['first_seed']} {config['synthetic']['corpus']['first_seed'] + config['synthetic']['corpus']['num_scenes'] - 1}",
    threads: config["threads"]["restorer"]
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("foundation_gates", "all"),
    benchmark:
        benchmark_file("foundation_gates", "all")
    shell:
        "recondreamer foundation-gates --restorer {params.restorers} --pairs {input.pairs} --autoencoder {input.autoencoder} "
        "--gate-scenes {input.scenes} --eval-metrics {input.eval_metrics} --detector {input.detector} --lane-model {input.lanes} --gate-seeds {params.gate_seeds} "
        "--corpus-seeds {params.corpus_seeds} --out {output.gates} --threads {threads} > {log} 2>&1"


rule publish_weights:
    input:
        files=list(published_files().values()),
        gates=results("foundation", "gates.json"),
    output:
        os.path.join(FOUNDATION["out_dir"], "manifest.json"),
    params:
        files=" ".join(f"{name}={path}" for name, path in published_files().items()),
        out=lambda wildcards, output: parent(output[0]),
        preset=config["synthetic"]["corpus"]["preset"],
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("publish_weights", "all"),
    benchmark:
        benchmark_file("publish_weights", "all")
    shell:
        "recondreamer weights publish {params.files} --gates {input.gates} --corpus-preset {params.preset} "
        "--out {params.out} > {log} 2>&1"
