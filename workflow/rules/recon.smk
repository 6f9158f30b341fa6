# Baseline reconstructions (one per segment and backbone) and the corpus reconstructions that only
# feed the restoration pairs. Runs are rendered along the evaluated trajectories by `evaluate`.

RECON_OPTIONS = (
    f"--preset {config['recon']['preset']} --seed {config['recon']['seed']} --backend {config['recon']['backend']} "
    + " ".join(text for text in (option("--iterations", config["recon"]["iterations"]), option("--device", config["recon"]["device"])) if text)
)


rule train_baseline:
    input:
        scene=results("scenes", "{segment}"),
    output:
        results("runs", "{segment}", "baseline-{backbone}", "model.pt"),
    params:
        run=lambda wildcards: run_dir(RESULTS, wildcards.segment, f"baseline-{wildcards.backbone}"),
        options=RECON_OPTIONS,
    threads: config["threads"]["recon"]
    priority: FEEDER_PRIORITY
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("train_baseline", "{segment}/{backbone}"),
    benchmark:
        benchmark_file("train_baseline", "{segment}/{backbone}")
    shell:
        "recondreamer train-recon --scene {input.scene} --model {wildcards.backbone} --out {params.run} "
        "{params.options} --threads {threads} > {log} 2>&1"


rule train_corpus_recon:
    input:
        scene=results("corpus", "{corpus_scene}"),
    output:
        results("corpus_runs", "{corpus_scene}", "{backbone}", "model.pt"),
    params:
        run=lambda wildcards: results("corpus_runs", wildcards.corpus_scene, wildcards.backbone),
        options=RECON_OPTIONS,
    threads: config["threads"]["recon"]
    priority: RESTORER_PATH_PRIORITY
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("train_corpus_recon", "{corpus_scene}/{backbone}"),
    benchmark:
        benchmark_file("train_corpus_recon", "{corpus_scene}/{backbone}")
    shell:
        "recondreamer train-recon --scene {input.scene} --model {wildcards.backbone} --out {params.run} "
        "{params.options} --threads {threads} > {log} 2>&1"
