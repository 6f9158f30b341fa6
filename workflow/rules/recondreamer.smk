# ReconDreamer (reconstruction with online restoration and the Progressive Data Update Strategy)
# and the DriveDreamer4D baseline (training-free generated novel-trajectory videos).

PDUS_OPTIONS = " ".join(
    option(flag, config["methods"][key])
    for flag, key in (
        ("--update-every", "update_every"),
        ("--max-offset", "max_offset"),
        ("--restore-sample-steps", "restore_steps"),
        ("--restore-strength", "restore_strength"),
    )
)
# The DriveRestorer inside the loop runs on restorer.device when set (else on the recon's device).
RESTORER_PDUS_OPTIONS = PDUS_OPTIONS + ("" if config["restorer"]["device"] is None else " " + option("--restorer-device", config["restorer"]["device"]))


rule train_recondreamer:
    input:
        scene=results("scenes", "{segment}"),
        restorer=lambda wildcards: restorer_checkpoint(wildcards.restorer),
    output:
        results("runs", "{segment}", "recondreamer-{backbone}-{restorer}-stride{stride}", "model.pt"),
    params:
        run=lambda wildcards: run_dir(RESULTS, wildcards.segment, f"recondreamer-{wildcards.backbone}-{wildcards.restorer}-stride{wildcards.stride}"),
        options=RECON_OPTIONS,
        pdus=RESTORER_PDUS_OPTIONS,
    threads: config["threads"]["recon"]
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("train_recondreamer", "{segment}/{backbone}-{restorer}-stride{stride}"),
    benchmark:
        benchmark_file("train_recondreamer", "{segment}/{backbone}-{restorer}-stride{stride}")
    shell:
        "recondreamer train-recondreamer --scene {input.scene} --model {wildcards.backbone} "
        "--restorer {input.restorer} --stride {wildcards.stride} --out {params.run} {params.options} {params.pdus} "
        "--threads {threads} > {log} 2>&1"


# The oracle: ReconDreamer trained on the true views of each shifted trajectory instead of
# restored renders (synthetic segments only). Not a table row; the upper bound that issue 7's
# gate (benchmarks/methods_gate.py --oracle) compares against to separate PDUS from restorer quality.
rule train_recondreamer_truth:
    input:
        scene=results("scenes", "{segment}"),
    output:
        results("runs", "{segment}", "recondreamer-{backbone}-truth-stride{stride}", "model.pt"),
    params:
        run=lambda wildcards: run_dir(RESULTS, wildcards.segment, f"recondreamer-{wildcards.backbone}-truth-stride{wildcards.stride}"),
        options=RECON_OPTIONS,
        pdus=PDUS_OPTIONS,
    threads: config["threads"]["recon"]
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("train_recondreamer_truth", "{segment}/{backbone}-stride{stride}"),
    benchmark:
        benchmark_file("train_recondreamer_truth", "{segment}/{backbone}-stride{stride}")
    shell:
        "recondreamer train-recondreamer --scene {input.scene} --model {wildcards.backbone} "
        "--restorer truth --stride {wildcards.stride} --out {params.run} {params.options} {params.pdus} "
        "--threads {threads} > {log} 2>&1"


# DriveDreamer4D's videos depend on the segment and the world model only: generated once per
# segment and trajectory, read by the DriveDreamer4D run of every backbone. The seed (recon seed +
# the trajectory's index) is the one 'train-dd4d' would use when generating by itself.
rule generate_dd4d:
    input:
        scene=results("scenes", "{segment}"),
        world_model=model_path(config, "world_model", "dd2"),
    output:
        directory(results("dd4d_generated", "{segment}", "{trajectory}")),
    params:
        seed=lambda wildcards: config["recon"]["seed"] + DD4D_TRAJECTORIES.index(wildcards.trajectory),
        steps=option("--sample-steps", config["methods"]["dd4d_generate_steps"]) + RESTORER_DEVICE,
    threads: config["threads"]["restorer"]
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("generate_dd4d", "{segment}/{trajectory}"),
    benchmark:
        benchmark_file("generate_dd4d", "{segment}/{trajectory}")
    shell:
        "recondreamer dd4d-generate --world-model {input.world_model} --scene {input.scene} "
        "--trajectory {wildcards.trajectory} --out {output} --seed {params.seed} {params.steps} --threads {threads} > {log} 2>&1"


rule train_dd4d:
    input:
        scene=results("scenes", "{segment}"),
        generated=expand(results("dd4d_generated", "{{segment}}", "{trajectory}"), trajectory=DD4D_TRAJECTORIES),
    output:
        results("runs", "{segment}", "dd4d-{backbone}", "model.pt"),
    params:
        run=lambda wildcards: run_dir(RESULTS, wildcards.segment, f"dd4d-{wildcards.backbone}"),
        generated=lambda wildcards, input: parent(input.generated[0]),
        trajectories=",".join(DD4D_TRAJECTORIES),
        options=RECON_OPTIONS,
    threads: config["threads"]["recon"]
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("train_dd4d", "{segment}/{backbone}"),
    benchmark:
        benchmark_file("train_dd4d", "{segment}/{backbone}")
    shell:
        "recondreamer train-dd4d --scene {input.scene} --model {wildcards.backbone} --generated {params.generated} "
        "--trajectories {params.trajectories} --out {params.run} {params.options} --threads {threads} > {log} 2>&1"
