use super::*;
use std::os::unix::fs::symlink;

/// A scratch directory of the test's own (private, removed at the end).
fn scratch(tag: &str) -> PrivateDir {
    PrivateDir::create(&format!("bb-files-{tag}-{}-", std::process::id())).unwrap()
}

#[test]
fn a_private_dir_is_fresh_0700_ours_and_removed_on_drop() {
    let a = scratch("fresh");
    let b = scratch("fresh");
    assert_ne!(a.path(), b.path(), "mkdtemp never reuses a name");
    assert_eq!(mode_of(a.path()).unwrap(), 0o700);
    check_private_dir(a.path()).unwrap();
    let p = a.path().to_path_buf();
    std::fs::write(p.join("x"), b"1").unwrap();
    drop(a);
    assert!(!p.exists());
}

#[test]
fn a_shared_or_linked_directory_is_not_private() {
    let d = scratch("shared");
    let open = d.path().join("open");
    std::fs::create_dir(&open).unwrap();
    std::fs::set_permissions(&open, std::fs::Permissions::from_mode(0o755)).unwrap();
    let e = check_private_dir(&open).unwrap_err();
    assert!(e.to_string().contains("0700"), "{e}");
    let inner = PrivateDir::create_in(d.path(), "inner").unwrap();
    let link = d.path().join("link");
    symlink(inner.path(), &link).unwrap();
    assert!(check_private_dir(&link).is_err(), "a link to a private dir");
    assert!(write_private(&open.join("f"), b"x", Durability::Synced).is_err());
    assert!(!open.join("f").exists());
}

#[test]
fn a_planted_link_in_a_private_dir_is_replaced_not_followed() {
    let d = scratch("plant");
    let victim = d.path().join("victim");
    std::fs::write(&victim, b"precious").unwrap();
    let target = d.path().join("filter.resume.json");
    symlink(&victim, &target).unwrap();
    // The temporary's name is not predictable; plant a link at the old
    // fixed name too (`<file>.tmp`).
    symlink(&victim, d.path().join("filter.resume.tmp")).unwrap();
    write_private(&target, b"{}", Durability::RunScoped).unwrap();
    assert_eq!(std::fs::read(&victim).unwrap(), b"precious");
    assert!(!std::fs::symlink_metadata(&target)
        .unwrap()
        .file_type()
        .is_symlink());
    assert_eq!(std::fs::read(&target).unwrap(), b"{}");
    assert_eq!(mode_of(&target).unwrap(), 0o600);
}

#[test]
fn reading_refuses_links_and_non_private_directories() {
    let d = scratch("read");
    let real = d.path().join("real");
    write_private(&real, b"ok", Durability::Synced).unwrap();
    assert_eq!(read_private(&real).unwrap(), b"ok");
    let link = d.path().join("link");
    symlink(&real, &link).unwrap();
    assert!(read_private(&link).is_err(), "read through a link");
    let open = d.path().join("open");
    std::fs::create_dir(&open).unwrap();
    std::fs::set_permissions(&open, std::fs::Permissions::from_mode(0o777)).unwrap();
    std::fs::write(open.join("f"), b"planted").unwrap();
    assert!(read_private(&open.join("f")).is_err());
}

#[test]
fn a_user_output_replaces_a_planted_link_and_keeps_no_temporary() {
    let d = scratch("out");
    let victim = d.path().join("victim");
    std::fs::write(&victim, b"precious").unwrap();
    let report = d.path().join("report.json");
    symlink(&victim, &report).unwrap();
    replace_file(&report, b"{\"ok\":1}").unwrap();
    assert_eq!(std::fs::read(&victim).unwrap(), b"precious");
    assert_eq!(std::fs::read(&report).unwrap(), b"{\"ok\":1}");
    let names: Vec<_> = std::fs::read_dir(d.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names.len(), 2, "{names:?}");
    assert!(replace_file(d.path(), b"x").is_err(), "a directory target");
}

#[test]
fn a_streamed_output_refuses_a_link() {
    let d = scratch("stream");
    let victim = d.path().join("victim");
    std::fs::write(&victim, b"precious").unwrap();
    let t = d.path().join("timeline.jsonl");
    symlink(&victim, &t).unwrap();
    assert!(create_no_follow(&t).is_err());
    assert_eq!(std::fs::read(&victim).unwrap(), b"precious");
    let ok = d.path().join("ok.jsonl");
    create_no_follow(&ok).unwrap();
    assert!(ok.exists());
}
