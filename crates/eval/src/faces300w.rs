//! The faces-300w evaluation set (`../shared/data/faces-300w`, see its README): which
//! photos a run covers.

use std::path::Path;

/// The photos listed in `dir/manifest.csv` (paths relative to `dir`), in manifest order,
/// kept when they start with one of `subsets` (all when `subsets` is empty).
pub fn photos(dir: &Path, subsets: &[String]) -> std::io::Result<Vec<String>> {
    let manifest = std::fs::read_to_string(dir.join("manifest.csv"))?;
    Ok(manifest
        .lines()
        .skip(1)
        .filter_map(|l| l.split(',').next().map(String::from))
        .filter(|p| subsets.is_empty() || subsets.iter().any(|s| p.starts_with(s.as_str())))
        .collect())
}

#[cfg(test)]
mod tests {
    #[test]
    fn filters_by_prefix() {
        let dir = std::env::temp_dir().join(format!("faces300w-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(
            dir.join("manifest.csv"),
            "path,subset\nafw/1.jpg,afw\nhelen/testset/2.jpg,helen\nlfpw/trainset/3.png,lfpw\n",
        )
        .unwrap();
        assert_eq!(super::photos(&dir, &[]).unwrap().len(), 3);
        assert_eq!(
            super::photos(&dir, &["afw/".into(), "lfpw/".into()]).unwrap(),
            vec!["afw/1.jpg", "lfpw/trainset/3.png"]
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
