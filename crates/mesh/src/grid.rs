//! A uniform bucket grid: each cell of a regular grid over a rectangle lists
//! the items (triangles, segments) that touch it. One structure serves point
//! location in a mesh, crossing checks of polygon rings and clearance queries
//! while meshing.

use glam::DVec2;

#[derive(Debug, Clone)]
pub struct BucketGrid {
    lo: DVec2,
    cell: f64,
    columns: usize,
    rows: usize,
    /// Cell `k` lists `members[start[k]..start[k + 1]]`.
    start: Vec<u32>,
    members: Vec<u32>,
}

impl BucketGrid {
    /// A grid of square cells of side `cell` from `lo` covering `hi`, filled
    /// with `count` items; `cells_of(i, visit)` calls `visit(cell)` for each
    /// cell item `i` touches (see `BucketGrid::column`, `BucketGrid::row`).
    pub fn new(
        lo: DVec2,
        hi: DVec2,
        cell: f64,
        count: usize,
        cells_of: impl Fn(&GridShape, usize, &mut dyn FnMut(usize)),
    ) -> BucketGrid {
        let shape = GridShape {
            lo,
            cell,
            columns: ((hi.x - lo.x) / cell).floor() as usize + 1,
            rows: ((hi.y - lo.y) / cell).floor() as usize + 1,
        };
        let cells = shape.columns * shape.rows;
        let mut start = vec![0u32; cells + 1];
        for i in 0..count {
            cells_of(&shape, i, &mut |k| start[k + 1] += 1);
        }
        for k in 1..start.len() {
            start[k] += start[k - 1];
        }
        let mut fill = start.clone();
        let mut members = vec![0u32; start[cells] as usize];
        for i in 0..count {
            cells_of(&shape, i, &mut |k| {
                members[fill[k] as usize] = i as u32;
                fill[k] += 1;
            });
        }
        BucketGrid {
            lo,
            cell,
            columns: shape.columns,
            rows: shape.rows,
            start,
            members,
        }
    }

    pub fn shape(&self) -> GridShape {
        GridShape {
            lo: self.lo,
            cell: self.cell,
            columns: self.columns,
            rows: self.rows,
        }
    }

    pub fn cell_count(&self) -> usize {
        self.columns * self.rows
    }

    /// The items listed in cell `k`.
    pub fn members(&self, k: usize) -> &[u32] {
        &self.members[self.start[k] as usize..self.start[k + 1] as usize]
    }
}

/// The geometry of a grid: where its cells are.
#[derive(Debug, Clone, Copy)]
pub struct GridShape {
    pub lo: DVec2,
    pub cell: f64,
    pub columns: usize,
    pub rows: usize,
}

impl GridShape {
    /// The column holding `x`, clamped to the grid.
    pub fn column(&self, x: f64) -> usize {
        (((x - self.lo.x) / self.cell).floor().max(0.0) as usize).min(self.columns - 1)
    }

    /// The row holding `y`, clamped to the grid.
    pub fn row(&self, y: f64) -> usize {
        (((y - self.lo.y) / self.cell).floor().max(0.0) as usize).min(self.rows - 1)
    }

    /// Visits every cell overlapping the box `[a, b]`.
    pub fn visit_box(&self, a: DVec2, b: DVec2, visit: &mut dyn FnMut(usize)) {
        for r in self.row(a.y)..=self.row(b.y) {
            for c in self.column(a.x)..=self.column(b.x) {
                visit(r * self.columns + c);
            }
        }
    }
}
