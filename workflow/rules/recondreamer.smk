# ReconDreamer (reconstruction with online restoration and the Progressive Data Update Strategy)
# and the DriveDreamer4D baseline (training-free generated novel-trajectory videos).


rule train_recondreamer:
    input:
        scene=results("scenes", "{segment}"),
        restorer=results("models", "restorer_{restorer}.pt"),
    output:
        results("runs", "{segment}", "recondreamer-{backbone}-{restorer}-stride{stride}", "model.pt"),
    params:
        run=lambda wildcards: run_dir(RESULTS, wildcards.segment, f"recondreamer-{wildcards.backbone}-{wildcards.restorer}-stride{wildcards.stride}"),
        preset=config["recon"]["preset"],
    threads: config["threads"]["recon"]
    log:
        log_file("train_recondreamer", "{segment}/{backbone}-{restorer}-stride{stride}"),
    benchmark:
        benchmark_file("train_recondreamer", "{segment}/{backbone}-{restorer}-stride{stride}")
    shell:
        "recondreamer train-recondreamer --scene {input.scene} --model {wildcards.backbone} "
        "--restorer {input.restorer} --stride {wildcards.stride} --out {params.run} --preset {params.preset} > {log} 2>&1"


rule train_dd4d:
    input:
        scene=results("scenes", "{segment}"),
        world_model=results("models", "world_model_dd2.pt"),
    output:
        results("runs", "{segment}", "dd4d-{backbone}", "model.pt"),
    params:
        run=lambda wildcards: run_dir(RESULTS, wildcards.segment, f"dd4d-{wildcards.backbone}"),
        preset=config["recon"]["preset"],
    threads: config["threads"]["recon"]
    log:
        log_file("train_dd4d", "{segment}/{backbone}"),
    benchmark:
        benchmark_file("train_dd4d", "{segment}/{backbone}")
    shell:
        "recondreamer train-dd4d --scene {input.scene} --model {wildcards.backbone} "
        "--world-model {input.world_model} --out {params.run} --preset {params.preset} > {log} 2>&1"
