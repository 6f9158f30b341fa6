# The paper's five tables, the findings page, the figures, the novel-view clips, the configuration
# and the time per rule, all tagged for the Snakemake report.

rule run_config:
    # The config this run was made with, for the tables' notes (stand-ins, recipe, budgets); the
    # config is a param, so a changed config rewrites it and everything that reads it.
    output:
        results("run_config.yaml"),
    params:
        config=config,
    log:
        log_file("run_config", "all"),
    benchmark:
        benchmark_file("run_config", "all")
    run:
        write_run_config(params.config, output[0], log[0])


rule make_tables:
    input:
        metrics=all_metrics_files(),
        features=all_features_files(),
        win_rates=[path for path in [win_rates_file()] if path],
        run_config=results("run_config.yaml"),
        models=note_model_files(),
    output:
        table_outputs(),
    params:
        results=lambda wildcards, input: parent(input.metrics[0], 3),
        out=lambda wildcards, output: parent(output[0]),
        tables=" ".join(str(n) for n in TABLES),
        win_rates=lambda wildcards, input: option("--win-rates", input.win_rates[0] if input.win_rates else None),
        plan=plan_arguments(),
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("make_tables", "all"),
    benchmark:
        benchmark_file("make_tables", "all")
    shell:
        "recondreamer make-tables --results {params.results} --out {params.out} --tables {params.tables} "
        "{params.win_rates} --run-config {input.run_config} {params.plan} > {log} 2>&1"


rule findings:
    input:
        metrics=all_metrics_files(),
        features=all_features_files(),
        win_rates=[path for path in [win_rates_file()] if path],
        run_config=results("run_config.yaml"),
        models=note_model_files(),
    output:
        markdown=results("findings.md"),
        html=report(results("findings.html"), caption="../report/findings.rst", category="0. Findings", labels={"page": "findings"}),
        csv=results("findings.csv"),
    params:
        results=lambda wildcards, input: parent(input.metrics[0], 3),
        win_rates=lambda wildcards, input: option("--win-rates", input.win_rates[0] if input.win_rates else None),
        plan=plan_arguments(),
    threads: config["threads"]["evaluate"]
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("findings", "all"),
    benchmark:
        benchmark_file("findings", "all")
    shell:
        "recondreamer findings --results {params.results} --out {output.markdown} {params.win_rates} "
        "--run-config {input.run_config} {params.plan} > {log} 2>&1"


rule make_plots:
    input:
        metrics=all_metrics_files(),
        scenes=[scene_dir(s) for s in SEGMENTS],
        renders=[
            str(render_dir(RESULTS, s, m.run_id, config["report"]["qualitative_trajectory"])) for s in SEGMENTS for m in qualitative_methods()
        ],
    output:
        figure("metric_vs_shift.png", "metric_vs_shift", "Metrics", {"figure": "metric vs shift"}),
        figure("stride_curve.png", "stride_curve", "Metrics", {"figure": "stride curve"}),
        figure("restorer_bars.png", "restorer_bars", "Metrics", {"figure": "restorer backbones"}),
        [figure(f"qualitative_{s}.png", "qualitative", "Qualitative", {"segment": s}) for s in SEGMENTS],
    params:
        results=lambda wildcards, input: parent(input.metrics[0], 3),
        out=lambda wildcards, output: parent(output[0]),
        trajectory=config["report"]["qualitative_trajectory"],
        frames=" ".join(str(f) for f in config["report"]["qualitative_frames"]),
        dd4d=config["report"]["dd4d_backbone"],
        plan=plan_arguments(),
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("make_plots", "all"),
    benchmark:
        benchmark_file("make_plots", "all")
    shell:
        "recondreamer make-plots --results {params.results} --out {params.out} --qualitative-trajectory {params.trajectory} "
        "--qualitative-frames {params.frames} --dd4d-backbone {params.dd4d} {params.plan} > {log} 2>&1"


rule pdus_figure:
    input:
        lambda wildcards: run_model(wildcards.segment, PLAN.preference_method().run_id),
    output:
        figure("pdus_{segment}.png", "pdus", "PDUS progression", {"segment": "{segment}"}),
    params:
        run=lambda wildcards, input: parent(input[0]),
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("pdus_figure", "{segment}"),
    benchmark:
        benchmark_file("pdus_figure", "{segment}")
    shell:
        "recondreamer pdus-figure --run {params.run} --out {output} > {log} 2>&1"


rule restore_clip:
    # The main DriveRestorer applied once to the degraded baseline render of a clip: what restoration
    # alone gives, shown beside the ReconDreamer run trained with that restorer (the restorations
    # inside train-recondreamer use the same steps and strength).
    input:
        restorer=restorer_checkpoint(PLAN.preference_method().restorer),
        scene=results("scenes", "{segment}"),
        renders=qualitative_render("{segment}", PLAN.baseline(PLAN.ablation_backbone)),
    output:
        directory(results("clips", "{segment}", "restored")),
    params:
        trajectory=config["report"]["qualitative_trajectory"],
        options=" ".join([option("--sample-steps", config["methods"]["restore_steps"]), option("--strength", config["methods"]["restore_strength"]), RESTORER_DEVICE]),
    threads: config["threads"]["restorer"]
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("restore_clip", "{segment}"),
    benchmark:
        benchmark_file("restore_clip", "{segment}")
    shell:
        "recondreamer restore --restorer {input.restorer} --scene {input.scene} --renders {input.renders} "
        "--trajectory {params.trajectory} --out {output} {params.options} --threads {threads} > {log} 2>&1"


rule novel_view_clip:
    input:
        scene=results("scenes", "{segment}"),
        degraded=qualitative_render("{segment}", PLAN.baseline(PLAN.ablation_backbone)),
        restored=results("clips", "{segment}", "restored"),
        recondreamer=qualitative_render("{segment}", PLAN.preference_method()),
    output:
        gif=results("clips", "{segment}.gif"),
        webm=results("clips", "{segment}.webm"),
        html=report(results("clips", "{segment}.html"), caption="../report/novel_view_clip.rst", category="2. Figures", subcategory="Novel-view clips", labels={"segment": "{segment}"}),
    params:
        trajectory=config["report"]["qualitative_trajectory"],
        panels=lambda wildcards, input: clip_panel_arguments(input.degraded, input.restored, input.recondreamer),
        fps=config["report"]["clip_fps"],
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("novel_view_clip", "{segment}"),
    benchmark:
        benchmark_file("novel_view_clip", "{segment}")
    shell:
        "recondreamer novel-view-clip --scene {input.scene} --trajectory {params.trajectory} {params.panels} "
        "--out {output.gif} --fps {params.fps} > {log} 2>&1"


rule config_page:
    input:
        results("run_config.yaml"),
    output:
        report(results("run_config.html"), caption="../report/run_config.rst", category="4. Configuration", labels={"page": "configuration"}),
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("config_page", "all"),
    benchmark:
        benchmark_file("config_page", "all")
    shell:
        "recondreamer config-page {input} --out {output} > {log} 2>&1"


rule benchmark_summary:
    input:
        rules.make_tables.output,
        rules.findings.output,
        rules.make_plots.output,
        [results("plots", f"pdus_{s}.png") for s in SEGMENTS],
        results("study"),
        clip_files(),
        results("run_config.html"),
    output:
        report(results("benchmark_summary.html"), caption="../report/benchmarks.rst", category="3. Compute", labels={"summary": "time per rule"}),
        results("benchmark_summary.csv"),
        results("benchmark_summary.md"),
    params:
        root=results("benchmarks"),
        stem=lambda wildcards, output: os.path.splitext(output[0])[0],
    conda:
        "../envs/recondreamer.yaml"
    log:
        log_file("benchmark_summary", "all"),
    benchmark:
        benchmark_file("benchmark_summary", "all")
    shell:
        "recondreamer benchmark-summary {params.root} --out {params.stem} > {log} 2>&1"
