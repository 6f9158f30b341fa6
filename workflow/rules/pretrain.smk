# The generative models' pretraining on the corpus: latent autoencoder, then the world models
# standing in for Stable Diffusion (sd), Stable Video Diffusion (svd) and DriveDreamer-2 (dd2).

# ' --device D' where pretrain.device / restorer.device is set, else '': appended to an existing
# parameter, so that the default (null) leaves every command, and so every finished job, unchanged.
PRETRAIN_DEVICE = "" if config["pretrain"]["device"] is None else " " + option("--device", config["pretrain"]["device"])
RESTORER_DEVICE = "" if config["restorer"]["device"] is None else " " + option("--device", config["restorer"]["device"])


rule train_autoencoder:
    input:
        corpus_scene_dirs(),
    output:
        results("models", "autoencoder.pt"),
    params:
        corpus=lambda wildcards, input: parent(input[0]),
        steps=option("--steps", config["pretrain"]["autoencoder_steps"]),
        latent=option("--latent-channels", config["pretrain"]["latent_channels"]) + PRETRAIN_DEVICE,
        seed=config["pretrain"]["seed"],
    threads: config["threads"]["pretrain"]
    priority: RESTORER_PATH_PRIORITY
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("train_autoencoder", "all"),
    benchmark:
        benchmark_file("train_autoencoder", "all")
    shell:
        "recondreamer train-autoencoder --corpus {params.corpus} --out {output} {params.steps} {params.latent} "
        "--seed {params.seed} --threads {threads} > {log} 2>&1"


rule pretrain_world_model:
    input:
        corpus=corpus_scene_dirs(),
        autoencoder=results("models", "autoencoder.pt"),
    output:
        results("models", "world_model_{arch}.pt"),
    params:
        corpus=lambda wildcards, input: parent(input.corpus[0]),
        options=" ".join(
            option(flag, config["pretrain"][key])
            for flag, key in (("--steps", "world_model_steps"), ("--batch-size", "batch_size"), ("--window", "window"), ("--seed", "seed"))
        )
        + PRETRAIN_DEVICE,
    threads: config["threads"]["pretrain"]
    priority: RESTORER_PATH_PRIORITY
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("pretrain_world_model", "{arch}"),
    benchmark:
        benchmark_file("pretrain_world_model", "{arch}")
    shell:
        "recondreamer pretrain-world-model --arch {wildcards.arch} --corpus {params.corpus} "
        "--autoencoder {input.autoencoder} --out {output} {params.options} --threads {threads} > {log} 2>&1"
