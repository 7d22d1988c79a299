//! Where the gateway keeps what it makes for itself when the user named no path (the demo's
//! store, the OPC UA server's key and certificate): the state folder, never the working
//! directory. Under the packaged systemd unit it is the unit's `StateDirectory` (systemd says
//! where in `$STATE_DIRECTORY`), else `$XDG_STATE_HOME/drivebus`, else
//! `~/.local/state/drivebus`.

use std::ffi::OsString;
use std::path::PathBuf;

/// The state folder of this process (not created here).
pub fn state_dir() -> Result<PathBuf, String> {
    state_dir_from(|name| std::env::var_os(name))
}

/// [`state_dir`] with the environment read through `env`.
pub fn state_dir_from(env: impl Fn(&str) -> Option<OsString>) -> Result<PathBuf, String> {
    // Only absolute paths count: a relative one would land in the working directory.
    let absolute = |v: Option<OsString>| v.map(PathBuf::from).filter(|p| p.is_absolute());
    // systemd gives the unit's state folders separated by ':'; drivebus's is the first.
    let systemd =
        env("STATE_DIRECTORY").and_then(|v| v.to_str().and_then(|s| s.split(':').next()).map(OsString::from));
    if let Some(dir) = absolute(systemd) {
        return Ok(dir);
    }
    if let Some(dir) = absolute(env("XDG_STATE_HOME")) {
        return Ok(dir.join("drivebus"));
    }
    if let Some(home) = absolute(env("HOME")) {
        return Ok(home.join(".local/state/drivebus"));
    }
    Err("no state folder: neither $STATE_DIRECTORY, $XDG_STATE_HOME nor $HOME is an absolute path".into())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn env<'a>(vars: &'a [(&'a str, &'a str)]) -> impl Fn(&str) -> Option<OsString> + 'a {
        move |name| vars.iter().find(|(k, _)| *k == name).map(|(_, v)| OsString::from(v))
    }

    #[test]
    fn systemd_then_xdg_then_home_and_never_a_relative_path() {
        let all = [
            ("STATE_DIRECTORY", "/var/lib/drivebus:/var/lib/other"),
            ("XDG_STATE_HOME", "/x"),
            ("HOME", "/h"),
        ];
        assert_eq!(state_dir_from(env(&all)).unwrap(), PathBuf::from("/var/lib/drivebus"));
        assert_eq!(
            state_dir_from(env(&[("XDG_STATE_HOME", "/x"), ("HOME", "/h")])).unwrap(),
            PathBuf::from("/x/drivebus")
        );
        assert_eq!(
            state_dir_from(env(&[("XDG_STATE_HOME", "rel"), ("HOME", "/h")])).unwrap(),
            PathBuf::from("/h/.local/state/drivebus")
        );
        assert!(state_dir_from(env(&[("HOME", "here")])).is_err());
        assert!(state_dir_from(env(&[])).unwrap_err().contains("$HOME"));
    }
}
