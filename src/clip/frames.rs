//! The tick's inner steps: taking finished reads under the budget, the frames a move crosses, the settled regions, the tiles asked for, the paging report and the min LOD.

use super::*;

impl Clipmap {
    /// Takes finished reads (each already in its slot) until the tick's budget is spent; returns
    /// (tiles admitted, tiles replaced in their slots, left for the next tick).
    pub(super) fn take_reads(&mut self, started: Instant) -> (u64, u64, usize) {
        self.backlog.extend(self.queues.drain());
        // The stream servers that measured a read this tick, and the tiles each delivered.
        let streams = self.controller.as_ref().map_or(0, |c| c.latency.stream_count());
        let mut sampled = vec![false; streams];
        let mut taken = vec![0u64; streams];
        let budget = self.settings.budget_ns.map(Duration::from_nanos);
        let mut admitted = 0;
        let mut replaced = 0;
        let mut n = 0u32;
        while let Some(done) = self.backlog.pop_front() {
            match done.outcome {
                Outcome::Filled(generation, delivered) => match self.cache.admit(done.tile, generation, delivered) {
                    Admit::Admitted => {
                        admitted += 1;
                        if let Some(c) = &mut self.controller {
                            if let Some((at, whole, stream)) = c.asked.remove(&done.tile) {
                                if whole {
                                    c.latency.sample(stream, self.tick.saturating_sub(at));
                                    sampled[stream] = true;
                                }
                                taken[stream] += 1;
                            }
                        }
                        if delivered == crate::source::Delivered::Default {
                            self.stats.default_tiles += 1;
                        }
                    }
                    // A refreshed tile's new texels (not a read the paging asked for).
                    Admit::Replaced => replaced += 1,
                    Admit::Stale => self.stats.late_tiles += 1,
                },
                // A simulated disk spent its reads for the tick: the tile stays wanted.
                Outcome::Failed(_, SourceError::Busy { .. }) => {
                    self.stats.reads_put_off += 1;
                    self.cache.mark_not_read(done.tile);
                }
                Outcome::NotWanted => {
                    self.stats.late_tiles += 1;
                    self.cache.mark_not_read(done.tile);
                }
                Outcome::Failed(generation, e) => {
                    tracing::debug!("tile read failed: {e}");
                    self.stats.read_faults.add(e.kind());
                    let retry_at = self.tick + self.settings.retry_after_ticks;
                    self.cache.mark_failed(done.tile, generation, e.kind(), retry_at);
                }
            }
            n += 1;
            if n.is_multiple_of(16) && budget.is_some_and(|b| started.elapsed() >= b) {
                break;
            }
        }
        self.stats.tiles_read += admitted;
        self.stats.tiles_replaced += replaced;
        if let Some(c) = &mut self.controller {
            for (stream, _) in sampled.iter().enumerate().filter(|(_, &measured)| !measured) {
                c.latency.rest(stream);
            }
            for (stream, &d) in taken.iter().enumerate() {
                let asked = std::mem::take(&mut c.asked_now[stream]);
                c.latency.count(stream, asked, d);
            }
        }
        (admitted, replaced, self.backlog.len())
    }

    /// Moves every level's frame to the new centre; returns each level's velocity in its texels.
    pub(super) fn move_frames(&mut self, centre: [i64; 2], velocity: [i64; 2]) -> Vec<[i64; 2]> {
        let mut out = Vec::with_capacity(self.levels.len());
        let others = self.views_windows();
        if let Some(c) = &mut self.controller {
            // A move of more than a window is a jump: the read-ahead restarts centred.
            c.motion.update(velocity, self.desc.clip_size());
        }
        for (k, level) in self.levels.iter_mut().enumerate() {
            let k32 = k as u32;
            let c = aligned_centre(centre, k32, self.settings.centre_alignment);
            let v = velocity.map(|x| if x != 0 && (x >> k32.min(63)) == 0 { x.signum() } else { x >> k32.min(63) });
            let previous = level.frame.mem;
            level.frame = level.shape.frame(c, self.border, v);
            // With further views, the grid holds the union of their windows where it can; a level
            // no view shows (their LOD windows) holds nothing and reads nothing.
            let own = if self.views.primary_lod.shows(k32) { level.frame.tex } else { Rect::EMPTY };
            let tex = views::mem_window(&level.shape, own, &others[k]);
            if tex.is_empty() {
                level.frame.mem = Rect::EMPTY;
                out.push(v);
                continue;
            }
            // A wrapping level is placed as the middle of three copies of itself side by side
            // (no edge near its window along s), and its region moved back by a level's tiles.
            let (shape, tex, previous, back) = match level.shape.tile_period() {
                None => (level.shape, tex, previous, 0),
                Some(n) => {
                    let w = level.shape.size[0] as i64;
                    let wide =
                        LevelShape { size: [level.shape.size[0] * 3, level.shape.size[1]], wrap: false, ..level.shape };
                    let need = tiles_covering(tex, level.shape.tile);
                    let prev = crate::geom::shift_near(previous, n, need.s0);
                    let prev = if prev.is_empty() {
                        prev
                    } else {
                        Rect::new(prev.s0 + n as i64, prev.t0, prev.s1 + n as i64, prev.t1)
                    };
                    (wide, Rect::new(tex.s0 + w, tex.t0, tex.s1 + w, tex.t1), prev, n as i64)
                }
            };
            let mem = match &mut self.controller {
                None => self.settings.prefetch.policy().mem_region(&shape, tex, v, previous),
                // A grid a configuration fixes (`mem_region_size`, or its lookahead) is held whole,
                // as the configuration says, its spare tiles around the window: reported fixed.
                Some(_) if self.desc.mem_grid(k32).is_some() => {
                    PrefetchKind::Ring.policy().mem_region(&shape, tex, v, previous)
                }
                Some(ctl) => {
                    let smooth = ctl.motion.at_level(k32);
                    let speed = ctl.motion.speed_at_level(k32);
                    let jump = velocity.map(|x| x.unsigned_abs() > self.desc.clip_size());
                    // The latency of the stream servers that read this level's tiles.
                    let latency = ctl.latency.level(k);
                    let mut lead = [0; 2];
                    for a in 0..2 {
                        // The smoothed speed, or this tick's when it is faster (a flight that
                        // speeds up is led at once) and no jump.
                        let now = if jump[a] { 0.0 } else { v[a].unsigned_abs() as f64 };
                        let need = adaptive::lead_texels(speed[a].max(now), latency);
                        ctl.needed[k][a] = need;
                        // A still axis (or one just recentred by a jump) holds no lead.
                        lead[a] = if smooth[a] == 0 { 0 } else { adaptive::held_lead(ctl.lead[k][a], need) };
                    }
                    ctl.lead[k] = lead;
                    adaptive::region(&shape, tex, smooth, lead)
                }
            };
            level.frame.mem =
                if mem.is_empty() { mem } else { Rect::new(mem.s0 - back, mem.t0, mem.s1 - back, mem.t1) };
            out.push(v);
        }
        out
    }

    /// The part of level `k`'s valid region whose tiles are all settled: the whole region when
    /// they are, else the largest rectangle of settled tiles grown from the centre's tile (empty
    /// when that tile is not settled).
    pub(super) fn settled_region(&self, k: usize) -> Rect {
        self.settled_in(k, &self.levels[k].frame)
    }

    /// [`settled_region`](Self::settled_region) of any view's `frame` of level `k`: only tiles
    /// inside the level's new mem region count as settled (a tile about to leave it is not
    /// published, so no slot the tick reassigns lies under a published region).
    pub(super) fn settled_in(&self, k: usize, frame: &LevelFrame) -> Rect {
        let level = &self.levels[k];
        let valid = frame.valid;
        if valid.is_empty() {
            return Rect::EMPTY;
        }
        let tile = level.shape.tile;
        let tiles = tiles_covering(valid, tile);
        let mem = level.frame.mem;
        let period = level.shape.tile_period();
        // On a wrapping level tile columns run past the level's tiles: column U is U mod n.
        let settled = |s: i64, t: i64| {
            let s = period.map_or(s, |n| crate::geom::wrap(s, n) as i64);
            crate::geom::contains_wrapped(&mem, s, t, period)
                && self.cache.state(TileId::new(k as u32, s as u64, t as u64)).settled()
        };
        let all = |r: Rect| (r.t0..r.t1).all(|t| (r.s0..r.s1).all(|s| settled(s, t)));
        if all(tiles) {
            return valid;
        }
        let mut c = frame.centre;
        if let Some(w) = level.shape.texel_period() {
            // The centre's column nearest the window (its own may lie a level's width away).
            c[0] = crate::geom::shift_near(Rect::new(c[0], 0, c[0] + 1, 1), w, (valid.s0 + valid.s1) / 2).s0;
        }
        let cs = c[0].clamp(valid.s0, valid.s1 - 1).div_euclid(tile[0] as i64);
        let ct = c[1].clamp(valid.t0, valid.t1 - 1).div_euclid(tile[1] as i64);
        if !settled(cs, ct) {
            return Rect::EMPTY;
        }
        let mut r = Rect::new(cs, ct, cs + 1, ct + 1);
        loop {
            let mut grew = false;
            if r.s0 > tiles.s0 && all(Rect::new(r.s0 - 1, r.t0, r.s0, r.t1)) {
                r.s0 -= 1;
                grew = true;
            }
            if r.s1 < tiles.s1 && all(Rect::new(r.s1, r.t0, r.s1 + 1, r.t1)) {
                r.s1 += 1;
                grew = true;
            }
            if r.t0 > tiles.t0 && all(Rect::new(r.s0, r.t0 - 1, r.s1, r.t0)) {
                r.t0 -= 1;
                grew = true;
            }
            if r.t1 < tiles.t1 && all(Rect::new(r.s0, r.t1, r.s1, r.t1 + 1)) {
                r.t1 += 1;
                grew = true;
            }
            if !grew {
                break;
            }
        }
        let (tw, th) = (tile[0] as i64, tile[1] as i64);
        let r = valid.intersect(&Rect::new(r.s0 * tw, r.t0 * th, r.s1 * tw, r.t1 * th));
        // A region of a wrapping level starts inside the level (docs/SHM.md, "How a region
        // wraps"): one settled only past the seam is the same columns a width to the west.
        match level.shape.texel_period() {
            Some(w) if r.s0 >= w as i64 => Rect::new(r.s0 - w as i64, r.t0, r.s1 - w as i64, r.t1),
            _ => r,
        }
    }

    /// Gives the slots of tiles that left each mem region to the tiles that entered, and asks
    /// the read queues for every tile wanted now.
    pub(super) fn request_tiles(&mut self, velocities: &[[i64; 2]]) {
        let count = self.levels.len();
        let mut wanted = Vec::new();
        // A tile whose finished read waits in the backlog (a spent budget) is in its slot already:
        // asking for it again would read it twice.
        let waiting: std::collections::HashSet<TileId> = self.backlog.iter().map(|c| c.tile).collect();
        let views = self.views.live().next().is_some();
        for (k, level) in self.levels.iter().enumerate() {
            let k32 = k as u32;
            if views {
                self.stats.slots_reassigned_under_views += self.under_views_leaving(k, level.frame.mem);
            }
            self.stats.tiles_evicted += self.cache.set_mem_region(k32, level.frame.mem);
            for tile in self.cache.wanted(k32, self.tick) {
                if waiting.contains(&tile) {
                    continue;
                }
                let mut texels = tile_texels(level.shape.size, level.shape.tile, [tile.s, tile.t]);
                if let Some(w) = level.shape.texel_period() {
                    // Where the window sees the tile (a level's width away across the seam).
                    texels = crate::geom::shift_near(texels, w, (level.frame.tex.s0 + level.frame.tex.s1) / 2);
                }
                let p = if self.controller.is_some() {
                    soonest_first(k32, count, texels, level.frame.valid, level.shape.clip, velocities[k])
                } else {
                    priority(k32, count, texels, level.frame.valid, level.shape.clip, velocities[k])
                };
                let p = if views { self.view_priority(k, texels, p, self.controller.is_some()) } else { p };
                wanted.push(ReadRequest { tile, priority: p });
                self.cache.mark_loading(tile);
                // A tile replaced in its slot is no paging read: the read-ahead's latency is not
                // measured on it.
                let replacing = self.replacing.contains(&tile);
                if let Some(c) = self.controller.as_mut().filter(|_| !replacing) {
                    // Asked again every tick while it loads: the latency counts from the first.
                    // Only reads asked for while the level was whole measure the latency the
                    // read-ahead plans with: while it fills (a start, a jump, a source that
                    // cannot keep up) reads wait behind each other, which a lead cannot cure.
                    let whole = level.published == level.frame.valid;
                    if let std::collections::hash_map::Entry::Vacant(e) = c.asked.entry(tile) {
                        let stream = self.queues.stream_of(tile);
                        c.latency.note(k, stream);
                        c.asked_now[stream] += 1;
                        e.insert((self.tick, whole, stream));
                    }
                }
            }
        }
        self.queues.update(&wanted);
        if let Some(c) = &mut self.controller {
            // Tiles that left their mem region (their requests dropped) never come back, and a
            // failed read is asked for afresh after its retry delay: forget both.
            let cache = &self.cache;
            c.asked.retain(|&t, _| cache.state(t) == TileState::Loading);
        }
    }

    /// Each level's paging this tick and why, from the controller's choices and whether each
    /// level's valid region is whole (`complete`).
    pub(super) fn paging_report(&self, complete: &[bool]) -> Vec<adaptive::LevelPaging> {
        // Reads waiting in each stream server's queue.
        let pending: Vec<bool> = self.queues.stream_stats().iter().map(|q| q.pending > 0).collect();
        self.levels
            .iter()
            .enumerate()
            .map(|(k, l)| {
                let Some(c) = self.controller.as_ref().filter(|_| self.desc.mem_grid(k as u32).is_none()) else {
                    return adaptive::LevelPaging { grid: l.shape.grid, ..Default::default() };
                };
                let speed = c.motion.speed_at_level(k as u32).map(|x| x.ceil() as u64);
                let speed = if c.motion.at_level(k as u32) == [0, 0] { [0, 0] } else { speed };
                let mut reason = adaptive::reason(&l.shape, speed, c.needed[k], complete[k]);
                // Reads of this level's tiles wait in their stream servers' queues (any server's
                // before the level has asked for a tile).
                let mut streams = c.latency.streams_of(k).peekable();
                let backlog = if streams.peek().is_some() {
                    streams.any(|s| pending.get(s).copied().unwrap_or(false))
                } else {
                    pending.iter().any(|&p| p)
                };
                // A lead the grid cannot hold is the budget's doing only while the source keeps
                // up: reads waiting in the level's queues, or a queue delivering less than is
                // asked of it (a rate a lead cannot raise), make it the source's.
                let source_short = backlog || c.latency.level_short(k);
                if reason == adaptive::Reason::BudgetBound && source_short && !complete[k] {
                    reason = adaptive::Reason::SourceBound;
                }
                let need = tiles_covering(l.frame.tex, l.shape.tile);
                let (m, dir) = (l.frame.mem, c.motion.at_level(k as u32));
                let beyond = |a: usize| match dir[a].signum() {
                    1 => (if a == 0 { m.s1 - need.s1 } else { m.t1 - need.t1 }).max(0) as u64,
                    -1 => (if a == 0 { need.s0 - m.s0 } else { need.t0 - m.t0 }).max(0) as u64,
                    _ => 0,
                };
                if reason == adaptive::Reason::Fixed {
                    return adaptive::LevelPaging { grid: l.shape.grid, ..Default::default() };
                }
                adaptive::LevelPaging {
                    lead_tiles: [beyond(0), beyond(1)],
                    lead_texels: c.lead[k],
                    grid: l.shape.grid,
                    reason,
                    read_latency_ticks: c.latency.level(k),
                }
            })
            .collect()
    }

    pub(super) fn update_min_lod(&mut self, complete: &[bool]) {
        let target = target_min_lod(complete);
        // Until some level is shown there is nothing to fade from: the first picture comes at once.
        let fade = if self.min_lod >= self.levels.len() as f64 { 0 } else { self.settings.fade_ticks };
        let next = next_min_lod(self.min_lod, target, fade);
        if next > self.min_lod {
            self.stats.min_lod_raises += 1;
        } else if next < self.min_lod {
            self.stats.min_lod_fades += 1;
        }
        self.min_lod = next;
    }
}
