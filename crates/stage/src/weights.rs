//! What a puppet's painted weights and grid leave the stage as: the
//! weights file `save_weights` writes (a new versioned file beside the
//! mesh unless the stage file says to overwrite) and the lp-FFD grid a
//! client asks for.

use super::*;

impl WeightsFile {
    /// The `.mesh.json` text: the loaded mesh with the painted weights
    /// and depth layers.
    pub fn text(self) -> Result<String, CommandError> {
        let file = self.path.display().to_string();
        let fail = |source| CommandError::Weights {
            file: file.clone(),
            source,
        };
        let mut mesh = self.mesh;
        mesh.set_weights(self.weights).map_err(fail)?;
        let mesh = match self.layers {
            Some(layers) => mesh.with_layers(&file, Some(layers)).map_err(fail)?,
            None => mesh,
        };
        Ok(mesh.to_json())
    }

    /// Writes the file: over the mesh file (`save_weights = "overwrite"`)
    /// atomically, else as the next free `NAME.vN.mesh.json` beside it,
    /// created new so an existing file is never replaced. Returns the path
    /// written.
    pub fn save(self) -> Result<PathBuf, CommandError> {
        use std::io::Write;
        let path = self.path.clone();
        let mode = self.mode;
        let text = self.text()?;
        let failed = |file: &std::path::Path| {
            let file = file.display().to_string();
            move |source| CommandError::Write { file, source }
        };
        if mode == SaveWeights::Overwrite {
            puppetry_mesh::file::write_atomically(&path, text.as_bytes()).map_err(failed(&path))?;
            return Ok(path);
        }
        for n in 1..=u32::MAX {
            let target = versioned(&path, n);
            let mut file = match std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(&target)
            {
                Ok(file) => file,
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
                Err(e) => return Err(failed(&target)(e)),
            };
            let written = file
                .write_all(text.as_bytes())
                .and_then(|()| file.sync_all());
            if let Err(e) = written {
                let _ = std::fs::remove_file(&target);
                return Err(failed(&target)(e));
            }
            return Ok(target);
        }
        Err(failed(&path)(std::io::Error::other(
            "no free version number",
        )))
    }
}

impl Stage {
    /// The grid of a grid puppet for an export request: its size, rest
    /// and deformed handles (stage coordinates, row by row from the lower
    /// left).
    pub fn export_grid(&self, puppet: u32) -> Result<GridExport, CommandError> {
        let p = self.puppet(puppet)?;
        let Rig::Grid(r) = &p.rig else {
            return Err(CommandError::NoGrid { puppet });
        };
        let points = |v: &[DVec2]| v.iter().map(|q| [q.x, q.y]).collect::<Vec<_>>();
        let spec = r.ffd.spec();
        Ok(GridExport {
            puppet,
            columns: spec.columns,
            rows: spec.rows,
            rest: points(r.ffd.rest_grid()),
            grid: points(r.ffd.grid()),
        })
    }

    /// What saving the puppet's painted weights writes, to be turned into
    /// text off the stage thread ([`WeightsFile::text`]).
    pub fn weights_file(&self, puppet: u32) -> Result<WeightsFile, CommandError> {
        let p = self.puppet(puppet)?;
        if let Rig::Curve(_) = p.rig {
            return Err(CommandError::NoWeights { puppet });
        }
        Ok(WeightsFile {
            path: p.mesh_file.clone(),
            mesh: p.source_mesh.clone(),
            weights: p.weights.clone(),
            layers: p.layers.clone(),
            mode: p.save_weights,
        })
    }
}
