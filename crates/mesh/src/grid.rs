//! A uniform bucket grid: each cell of a regular grid over a rectangle lists
//! the items (triangles, segments) that touch it. One structure serves point
//! location in a mesh, crossing checks of polygon rings and clearance queries
//! while meshing.

use glam::DVec2;

/// Items (by index, below the count the grid was built with) bucketed by
/// the square cells they touch, in two flat arrays whatever the item count.
/// Built once, then only read: [`BucketGrid::members`] of a cell index from
/// [`BucketGrid::shape`].
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
    /// cell item `i` touches (see [`GridShape::column`], [`GridShape::row`]).
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

    /// Where the grid's cells are, to turn points into cell indices.
    pub fn shape(&self) -> GridShape {
        GridShape {
            lo: self.lo,
            cell: self.cell,
            columns: self.columns,
            rows: self.rows,
        }
    }

    /// How many cells the grid has (columns × rows): every cell index is
    /// below it.
    pub fn cell_count(&self) -> usize {
        self.columns * self.rows
    }

    /// The items listed in cell `k`.
    pub fn members(&self, k: usize) -> &[u32] {
        &self.members[self.start[k] as usize..self.start[k + 1] as usize]
    }
}

/// The geometry of a grid: where its cells are. Cell `k` is in row
/// `k / columns`, column `k % columns`, counted from `lo`.
#[derive(Debug, Clone, Copy)]
pub struct GridShape {
    /// The corner with the lowest x and y, where row 0, column 0 starts.
    pub lo: DVec2,
    /// The side of every cell, in the items' coordinate units.
    pub cell: f64,
    /// Cells along x; at least 1.
    pub columns: usize,
    /// Cells along y; at least 1.
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
