# Evaluation segments (synthetic world or converted Waymo tfrecords) and the synthetic corpus.

if config["source"] == "synthetic":

    rule synth_segment:
        output:
            directory(results("scenes", "{segment}")),
        params:
            seed=lambda wildcards: config["synthetic"]["segments"][wildcards.segment],
            preset=config["synthetic"]["preset"],
        priority: RESTORER_PATH_PRIORITY
        conda:
            "../envs/recondreamer.yaml"
        log:
            log_file("synth_segment", "{segment}"),
        benchmark:
            benchmark_file("synth_segment", "{segment}")
        shell:
            "recondreamer synth --seed {params.seed} --preset {params.preset} --scene-id {wildcards.segment} "
            "--out {output} > {log} 2>&1"

else:

    rule convert_waymo:
        input:
            lambda wildcards: os.path.join(config["waymo"]["tfrecord_dir"], config["waymo"]["segments"][wildcards.segment]["file"]),
        output:
            directory(results("scenes", "{segment}")),
        params:
            start=lambda wildcards: config["waymo"]["segments"][wildcards.segment].get("start", 0),
            end=lambda wildcards: option("--end", config["waymo"]["segments"][wildcards.segment].get("end")),
            camera=config["waymo"]["camera"],
        conda:
            "../envs/recondreamer.yaml"
        log:
            log_file("convert_waymo", "{segment}"),
        benchmark:
            benchmark_file("convert_waymo", "{segment}")
        shell:
            "recondreamer convert-waymo {input} --out {output} --start {params.start} {params.end} "
            "--camera {params.camera} > {log} 2>&1"


rule synth_corpus_scene:
    output:
        directory(results("corpus", "{corpus_scene}")),
    params:
        seed=lambda wildcards: config["synthetic"]["corpus"]["first_seed"] + CORPUS_SCENES.index(wildcards.corpus_scene),
        preset=config["synthetic"]["corpus"]["preset"],
    priority: RESTORER_PATH_PRIORITY
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("synth_corpus_scene", "{corpus_scene}"),
    benchmark:
        benchmark_file("synth_corpus_scene", "{corpus_scene}")
    shell:
        "recondreamer synth --seed {params.seed} --preset {params.preset} --scene-id {wildcards.corpus_scene} "
        "--out {output} > {log} 2>&1"
