//! `lpm sweep` and `lpm solve --task`: expansion of frames and parameters, reruns, concurrent runs
//! of one task, `--status`, the sbatch script; and a real single-node Slurm (slurmctld + slurmd on
//! localhost, configured by the test in a temporary directory) running a 4-task array in which one
//! task is killed mid-solve by `scontrol requeue` and resumes, every result equal to a direct solve.
//! If Slurm cannot be started the test fails with the reason; it never skips.
use crate::common::{killable_cloud_scene, lpm_command, temp_dir};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

const BASE: &str = r#"
[volume]
raw = "density_{frame:02}.raw"
dims = [16, 16, 16]
[medium]
sigma_t = 0.8
albedo = 0.8
[[lights]]
kind = "sky"
radiance = 1.0
[solver]
directions_per_face = 2
max_orders = 3
tolerance = 1e-12
"#;

fn run(cmd: &mut Command) -> Output {
    cmd.output().expect("run a command")
}

fn ok(o: &Output) -> String {
    assert!(
        o.status.success(),
        "failed: {}\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn direct_fluence(dir: &Path, scene: &Path, name: &str) -> Vec<u8> {
    let out = dir.join(name);
    ok(&run(&mut lpm_command(&["solve", scene.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-image"])));
    std::fs::read(out.join("fluence.raw")).unwrap()
}

#[test]
fn sweep_expands_reruns_and_locks() {
    let dir = temp_dir("sweep");
    for (frame, density) in [(1, 0.5f32), (2, 1.5f32)] {
        let bytes: Vec<u8> = (0..16 * 16 * 16).flat_map(|_| density.to_le_bytes()).collect();
        std::fs::write(dir.join(format!("density_{frame:02}.raw")), bytes).unwrap();
    }
    std::fs::write(dir.join("base.toml"), BASE).unwrap();
    let manifest = dir.join("anim.toml");
    std::fs::write(
        &manifest,
        "scene = \"base.toml\"\n[frames]\nfirst = 1\nlast = 2\n[parameters]\n\"medium.albedo\" = [0.5, 0.9]\n[solve]\nno_image = true\n[slurm]\ntime = \"00:30:00\"\ngpus = 1\nmax_running = 2\n",
    )
    .unwrap();
    let m = manifest.to_str().unwrap();
    let out = ok(&run(&mut lpm_command(&["sweep", m, "--slurm"])));
    assert!(out.contains("4 tasks"), "{out}");
    let tasks_dir = dir.join("anim.tasks");
    let list: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(tasks_dir.join("tasks.json")).unwrap()).unwrap();
    let list = list.as_array().unwrap();
    assert_eq!(list.len(), 4);
    assert_eq!((list[1]["frame"].as_i64(), list[1]["parameters"]["medium.albedo"].as_f64()), (Some(1), Some(0.9)));
    assert_eq!((list[2]["frame"].as_i64(), list[2]["parameters"]["medium.albedo"].as_f64()), (Some(2), Some(0.5)));
    let scene2 = std::fs::read_to_string(tasks_dir.join("task-0002/scene.toml")).unwrap();
    assert!(scene2.contains(&format!("{}", dir.join("density_02.raw").display())), "{scene2}");
    let script = std::fs::read_to_string(tasks_dir.join("sweep.sbatch")).unwrap();
    for line in ["#SBATCH --array=0-3%2", "#SBATCH --requeue", "#SBATCH --gres=gpu:1", "#SBATCH --time=00:30:00"] {
        assert!(script.contains(line), "{line} missing from\n{script}");
    }
    assert!(script.contains("--task \"$SLURM_ARRAY_TASK_ID\""), "{script}");

    // Task 2 by number, task 1 through SLURM_ARRAY_TASK_ID; each equals a direct solve of its scene.
    ok(&run(&mut lpm_command(&["solve", m, "--task", "2"])));
    ok(&run(lpm_command(&["solve", m, "--task"]).env("SLURM_ARRAY_TASK_ID", "1")));
    for t in [1, 2] {
        let task = tasks_dir.join(format!("task-000{t}"));
        assert!(
            std::fs::read(task.join("out/fluence.raw")).unwrap()
                == direct_fluence(&dir, &task.join("scene.toml"), &format!("direct{t}")),
            "task {t} differs from a direct solve"
        );
    }
    // Frames differ, parameters differ.
    let f = |t: u32| std::fs::read(tasks_dir.join(format!("task-000{t}/out/fluence.raw"))).unwrap();
    assert!(f(1) != f(2));
    // A rerun of a done task does nothing.
    let again = ok(&run(&mut lpm_command(&["solve", m, "--task", "2"])));
    assert!(again.contains("already done"), "{again}");
    let o = run(&mut lpm_command(&["solve", m, "--task", "7"]));
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("there is no task 7"));

    // Two runs of one task at once: the second is refused while the first holds the task.
    let slow_dir = dir.join("slow");
    std::fs::create_dir_all(&slow_dir).unwrap();
    std::fs::write(slow_dir.join("slow.toml"), killable_cloud_scene([32, 30, 34], 10)).unwrap();
    std::fs::write(slow_dir.join("m.toml"), "scene = \"slow.toml\"\n[solve]\nno_image = true\n").unwrap();
    let sm = slow_dir.join("m.toml");
    let mut first = lpm_command(&["solve", sm.to_str().unwrap(), "--task", "0"]).stdout(Stdio::null()).spawn().unwrap();
    let status = slow_dir.join("m.tasks/task-0000/status.json");
    let t = Instant::now();
    while !status.exists() {
        assert!(t.elapsed() < Duration::from_secs(60), "the first run never started");
        std::thread::sleep(Duration::from_millis(20));
    }
    let o = run(&mut lpm_command(&["solve", sm.to_str().unwrap(), "--task", "0"]));
    assert!(first.try_wait().unwrap().is_none(), "the first run ended too soon to test the lock");
    assert_eq!(o.status.code(), Some(1));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("already being solved"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let st = ok(&run(&mut lpm_command(&["sweep", sm.to_str().unwrap(), "--status"])));
    assert!(st.contains("1 running"), "{st}");
    assert!(first.wait().unwrap().success());

    let st = ok(&run(&mut lpm_command(&["sweep", m, "--status"])));
    assert!(st.contains("4 tasks: 2 pending, 2 done"), "{st}");

    // --collect: one row per task, its frame and parameters against its results (grey: one
    // column per quantity), empty cells for the tasks not done; the JSON says the same.
    let said = ok(&run(&mut lpm_command(&["sweep", m, "--collect"])));
    assert!(said.contains("4 tasks (2 done)"), "{said}");
    let csv = std::fs::read_to_string(tasks_dir.join("results.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(
        lines[0], "task,frame,medium.albedo,status,orders,converged,seconds,lit_face,R,T,absorptance,error",
        "{csv}"
    );
    assert_eq!(lines.len(), 5, "{csv}");
    assert!(lines[1].starts_with("0,1,0.5,pending,,,,,,,,"), "{csv}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(tasks_dir.join("results.json")).unwrap()).unwrap();
    for t in [1usize, 2] {
        let cells: Vec<&str> = lines[t + 1].split(',').collect();
        assert_eq!(cells[3], "done", "{csv}");
        let row = &json[t];
        let report: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(tasks_dir.join(format!("task-000{t}/out/report.json"))).unwrap(),
        )
        .unwrap();
        assert_eq!(row["orders"], report["orders"]);
        assert_eq!(row["absorptance"], report["energy"]["absorptance"], "grey: one entry");
        assert_eq!(cells[10].parse::<f64>().unwrap(), report["energy"]["absorptance"][0].as_f64().unwrap());
        let r = row["R"][0].as_f64().unwrap();
        assert!(r > 0.0 && r < 1.0 && row["T"][0].as_f64().unwrap() > 0.0, "{row}");
        assert_eq!(row["parameters"]["medium.albedo"].as_f64(), Some([0.9, 0.5][t - 1]));
    }
    // A sky all round: more absorbed at the lower albedo (task 2: albedo 0.5) than at 0.9 (task 1).
    assert!(json[2]["absorptance"][0].as_f64() > json[1]["absorptance"][0].as_f64());
}

/// A manifest changed under a solved task: `lpm sweep` is refused before it writes anything (every
/// task's scene and record, and tasks.json, byte-identical after), and `--collect` labels the solved
/// task with the albedo it was solved at, not the manifest's new one (issue 57 item 13: task 0's
/// scene was rewritten before task 1 refused, and task 1, solved at 0.9, was collected as 0.3).
#[test]
fn a_changed_sweep_writes_nothing_and_collect_keeps_each_tasks_own_labels() {
    let dir = temp_dir("sweep-changed");
    let bytes: Vec<u8> = (0..16 * 16 * 16).flat_map(|_| 1.0f32.to_le_bytes()).collect();
    std::fs::write(dir.join("density.raw"), bytes).unwrap();
    std::fs::write(dir.join("base.toml"), BASE.replace("density_{frame:02}.raw", "density.raw")).unwrap();
    let manifest = dir.join("m.toml");
    let write_manifest = |albedos: &str| {
        std::fs::write(
            &manifest,
            format!("scene = \"base.toml\"\n[parameters]\n\"medium.albedo\" = [{albedos}]\n[solve]\nno_image = true\n"),
        )
        .unwrap()
    };
    write_manifest("0.5, 0.9");
    let m = manifest.to_str().unwrap();
    let out = ok(&run(&mut lpm_command(&["sweep", m])));
    assert!(out.contains("2 tasks"), "{out}");
    let tasks_dir = dir.join("m.tasks");
    ok(&run(&mut lpm_command(&["solve", m, "--task", "1"])));
    // tasks.json and every task's scene and record.
    let files = || -> Vec<(String, Vec<u8>)> {
        let mut files = vec![("tasks.json".to_string(), std::fs::read(tasks_dir.join("tasks.json")).unwrap())];
        for t in 0..2 {
            for name in ["scene.toml", "task.json"] {
                let path = format!("task-000{t}/{name}");
                files.push((path.clone(), std::fs::read(tasks_dir.join(&path)).unwrap()));
            }
        }
        files
    };
    let before = files();

    // Both albedos changed: task 1 is solved, so the sweep is refused, and task 0 (not started,
    // checked first) is not rewritten either.
    write_manifest("0.2, 0.3");
    let o = run(&mut lpm_command(&["sweep", m]));
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("task 1: its scene changed") && stderr.contains("nothing was written"), "{stderr}");
    for ((name, old), (_, new)) in before.iter().zip(files()) {
        assert!(*old == new, "{name} was rewritten by a refused sweep");
    }

    // --collect under the changed manifest: task 1 keeps the albedo it was solved at (from its
    // record, and from its scene.toml where it has none); task 0, not started, has the manifest's.
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(tasks_dir.join("task-0001/out/report.json")).unwrap()).unwrap();
    for without_record in [false, true] {
        if without_record {
            std::fs::remove_file(tasks_dir.join("task-0001/task.json")).unwrap();
        }
        let said = ok(&run(&mut lpm_command(&["sweep", m, "--collect"])));
        assert!(said.contains("2 tasks (1 done)"), "{said}");
        let csv = std::fs::read_to_string(tasks_dir.join("results.csv")).unwrap();
        let lines: Vec<&str> = csv.lines().collect();
        assert!(lines[1].starts_with("0,0.2,pending,"), "{csv}");
        assert!(lines[2].starts_with("1,0.9,done,"), "{csv}");
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(tasks_dir.join("results.json")).unwrap()).unwrap();
        assert_eq!(json[1]["parameters"]["medium.albedo"].as_f64(), Some(0.9), "{}", json[1]);
        assert_eq!(json[1]["absorptance"], report["energy"]["absorptance"]);
    }

    // Only the task not started changed: the sweep goes ahead and rewrites it (and its record).
    write_manifest("0.2, 0.9");
    ok(&run(&mut lpm_command(&["sweep", m])));
    let scene0 = std::fs::read_to_string(tasks_dir.join("task-0000/scene.toml")).unwrap();
    assert!(scene0.contains("albedo = 0.2"), "{scene0}");
    let record0: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(tasks_dir.join("task-0000/task.json")).unwrap()).unwrap();
    assert_eq!(record0["parameters"]["medium.albedo"].as_f64(), Some(0.2), "{record0}");
    let scene1 = &before.iter().find(|(n, _)| n == "task-0001/scene.toml").unwrap().1;
    assert!(std::fs::read(tasks_dir.join("task-0001/scene.toml")).unwrap() == *scene1, "task 1's scene rewritten");
}

/// A port p with p + 1 free too (slurmctld's and slurmd's), as the kernel hands out free ports:
/// a fixed or pid-derived choice can collide with a port some other process holds.
fn free_port_pair() -> u16 {
    for _ in 0..100 {
        let first = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let port = first.local_addr().unwrap().port();
        if port < u16::MAX && std::net::TcpListener::bind(("127.0.0.1", port + 1)).is_ok() {
            return port;
        }
    }
    panic!("no two consecutive free ports on 127.0.0.1");
}

/// `tools/slurm-local.conf.in` with its `@NAME@` fields filled in; a field left unfilled is a
/// failure here rather than a daemon's puzzling complaint.
fn fill_conf(fields: &[(&str, String)]) -> String {
    let mut conf = include_str!("../../tools/slurm-local.conf.in").to_string();
    for (name, value) in fields {
        conf = conf.replace(&format!("@{name}@"), value);
    }
    let unfilled = conf.lines().find(|l| !l.starts_with('#') && l.contains('@'));
    assert!(unfilled.is_none(), "tools/slurm-local.conf.in: a field left unfilled in {unfilled:?}");
    conf
}

/// A single-node Slurm cluster on localhost, stopped when dropped.
struct Slurm {
    conf: PathBuf,
    dir: PathBuf,
    daemons: Vec<Child>,
}

impl Slurm {
    fn start(dir: &Path) -> Slurm {
        for tool in ["slurmctld", "slurmd", "sbatch", "squeue", "scontrol"] {
            let found =
                Command::new("sh").arg("-c").arg(format!("command -v {tool} || test -x /usr/sbin/{tool}")).output();
            assert!(
                found.is_ok_and(|o| o.status.success()),
                "Slurm is not installed ({tool} not found): run tools/setup.sh (Debian package slurm-wlm)"
            );
        }
        let host = String::from_utf8(run(&mut Command::new("hostname")).stdout).unwrap().trim().to_string();
        let cpus = std::thread::available_parallelism().map_or(1, |n| n.get());
        let port = free_port_pair();
        std::fs::create_dir_all(dir.join("state")).unwrap();
        std::fs::create_dir_all(dir.join("spool")).unwrap();
        // The configuration tools/slurm-local.sh starts its cluster with, here with auth/none: the
        // daemons and clients are all on this host, run by one user, in a temporary cluster that
        // lives as long as the test; it spares a munge key and daemon.
        let conf = fill_conf(&[
            ("CLUSTER", "lpmtest".to_string()),
            ("HOST", host.clone()),
            ("PORT", port.to_string()),
            ("SLURMD_PORT", (port + 1).to_string()),
            ("AUTH", "auth/none".to_string()),
            ("CRED", "cred/none".to_string()),
            ("DIR", dir.display().to_string()),
            ("CPUS", cpus.to_string()),
            ("MEMORY_MB", "1000".to_string()),
            ("PARTITION", "test".to_string()),
        ]);
        let conf_path = dir.join("slurm.conf");
        std::fs::write(&conf_path, conf).unwrap();
        let mut slurm = Slurm { conf: conf_path.clone(), dir: dir.to_path_buf(), daemons: Vec::new() };
        for daemon in ["slurmctld", "slurmd"] {
            let child = Command::new(daemon)
                .arg("-D")
                .arg("-f")
                .arg(&conf_path)
                .stdout(Stdio::null())
                .stderr(std::fs::File::create(dir.join(format!("{daemon}.stderr"))).unwrap())
                .spawn()
                .unwrap_or_else(|e| panic!("cannot start {daemon}: {e}"));
            slurm.daemons.push(child);
        }
        let t = Instant::now();
        loop {
            let o = slurm.cmd("sinfo").args(["-h", "-o", "%t"]).output();
            if o.is_ok_and(|o| o.status.success() && String::from_utf8_lossy(&o.stdout).trim() == "idle") {
                return slurm;
            }
            if t.elapsed() > Duration::from_secs(60) {
                panic!("Slurm did not come up in 60 s:\n{}", slurm.logs());
            }
            std::thread::sleep(Duration::from_millis(250));
        }
    }

    fn cmd(&self, tool: &str) -> Command {
        let mut c = Command::new(tool);
        c.env("SLURM_CONF", &self.conf);
        c
    }

    fn logs(&self) -> String {
        ["slurmctld.log", "slurmd.log", "slurmctld.stderr", "slurmd.stderr"]
            .iter()
            .map(|f| format!("--- {f}\n{}", std::fs::read_to_string(self.dir.join(f)).unwrap_or_default()))
            .collect()
    }

    fn squeue(&self, job: &str) -> String {
        let o = run(self.cmd("squeue").args(["-h", "-j", job, "-o", "%i %t"]));
        String::from_utf8_lossy(&o.stdout).into_owned()
    }
}

impl Drop for Slurm {
    fn drop(&mut self) {
        for d in &mut self.daemons {
            // SIGTERM: the daemons shut down (slurmd ends its jobs' steps).
            // SAFETY: kill(2) on a child of this process.
            unsafe { libc::kill(d.id() as i32, libc::SIGTERM) };
        }
        for d in &mut self.daemons {
            let t = Instant::now();
            while t.elapsed() < Duration::from_secs(10) && d.try_wait().ok().flatten().is_none() {
                std::thread::sleep(Duration::from_millis(100));
            }
            let _ = d.kill();
            let _ = d.wait();
        }
    }
}

#[test]
fn slurm_array_with_a_killed_and_requeued_task() {
    let dir = temp_dir("slurm");
    let slurm = Slurm::start(&dir.join("cluster"));
    // 2×2×2 bricks, ten orders checkpointed one by one: the task is killed after its first
    // checkpoint, with nine orders to go.
    std::fs::write(dir.join("slow.toml"), killable_cloud_scene([24, 22, 26], 10)).unwrap();
    let manifest = dir.join("sweep.toml");
    std::fs::write(
        &manifest,
        "scene = \"slow.toml\"\n[parameters]\n\"medium.albedo\" = [0.5, 0.7, 0.8, 0.9]\n[solve]\nno_image = true\n[slurm]\ntime = \"00:20:00\"\ncpus_per_task = 1\n",
    )
    .unwrap();
    let o = run(lpm_command(&["sweep", manifest.to_str().unwrap(), "--submit"]).env("SLURM_CONF", &slurm.conf));
    let out = ok(&o);
    let job = out
        .lines()
        .find_map(|l| l.strip_prefix("submitted Slurm job "))
        .unwrap_or_else(|| panic!("no job id in {out}"))
        .trim()
        .to_string();
    let tasks = dir.join("sweep.tasks");

    // Kill task 3 mid-solve (after a checkpoint, before its report) by requeueing it, as a
    // preemption would; it must resume from its checkpoint.
    let task3 = tasks.join("task-0003/out");
    let t = Instant::now();
    loop {
        if task3.join(".lpm-work/checkpoint.json").exists() {
            break;
        }
        assert!(!task3.join("report.json").exists(), "task 3 finished before it could be killed");
        assert!(t.elapsed() < Duration::from_secs(300), "task 3 never checkpointed:\n{}", slurm.logs());
        std::thread::sleep(Duration::from_millis(10));
    }
    let o = run(slurm.cmd("scontrol").args(["requeue", &format!("{job}_3")]));
    assert!(o.status.success(), "scontrol requeue: {}", String::from_utf8_lossy(&o.stderr));
    assert!(!task3.join("report.json").exists(), "task 3 finished before it was killed");
    // A requeued job, once pending again, waits for a begin time minutes away; let it start now.
    let task = format!("{job}_3");
    let t = Instant::now();
    while !slurm.squeue(&task).contains(" PD") {
        assert!(t.elapsed() < Duration::from_secs(60), "task 3 not pending after requeue: {}", slurm.squeue(&task));
        std::thread::sleep(Duration::from_millis(100));
    }
    let o = run(slurm.cmd("scontrol").args(["update", &format!("jobid={task}"), "StartTime=now"]));
    assert!(o.status.success(), "scontrol update: {}", String::from_utf8_lossy(&o.stderr));

    let t = Instant::now();
    while !slurm.squeue(&job).trim().is_empty() {
        assert!(
            t.elapsed() < Duration::from_secs(600),
            "the array did not finish: {}\n{}",
            slurm.squeue(&job),
            slurm.logs()
        );
        std::thread::sleep(Duration::from_millis(500));
    }

    let st = ok(&run(&mut lpm_command(&["sweep", manifest.to_str().unwrap(), "--status"])));
    assert!(st.contains("4 tasks: 4 done"), "{st}\n{}", slurm.logs());
    let attempts = std::fs::read_to_string(tasks.join("task-0003/attempts.log")).unwrap();
    let lines: Vec<&str> = attempts.lines().collect();
    assert_eq!(lines.len(), 2, "task 3 should have run twice:\n{attempts}");
    assert!(lines[0].contains("started") && lines[1].contains("resumed after order"), "{attempts}");
    assert!(lines[1].contains("Slurm job"), "{attempts}");
    for t in 0..4 {
        let task = tasks.join(format!("task-000{t}"));
        assert!(
            std::fs::read(task.join("out/fluence.raw")).unwrap()
                == direct_fluence(&dir, &task.join("scene.toml"), &format!("direct{t}")),
            "task {t}: the Slurm result differs from a direct solve"
        );
    }
}
