//! The client's worker list, by page or by cursor.

use super::{ApiClient, ClientError};
use pathfarm_wire::api::WorkerList;
use reqwest::Method;

impl ApiClient {
    /// One page of the workers (`page` from 1; at most 1000 a page).
    pub async fn workers_page(&self, page: u32, per_page: u32) -> Result<WorkerList, ClientError> {
        Self::json(self.request(Method::GET, "/api/v1/workers").query(&[
            ("page", page.to_string()),
            ("per_page", per_page.to_string()),
        ]))
        .await
    }

    /// The page of workers after cursor `after` (the `next` of the page before; `None`: the
    /// first page).
    pub async fn workers_after(
        &self,
        after: Option<&str>,
        per_page: u32,
    ) -> Result<WorkerList, ClientError> {
        let mut query = vec![("per_page", per_page.to_string())];
        if let Some(after) = after {
            query.push(("after", after.to_string()));
        }
        Self::json(self.request(Method::GET, "/api/v1/workers").query(&query)).await
    }

    /// Every worker, page after page by cursor, as one list: each worker registered before the
    /// first page and not collected before the last is in it exactly once, however the farm
    /// changes while the pages are read.
    pub async fn workers(&self) -> Result<WorkerList, ClientError> {
        const PER_PAGE: u32 = 1000;
        let mut all = Vec::new();
        let mut after: Option<String> = None;
        loop {
            let list = self.workers_after(after.as_deref(), PER_PAGE).await?;
            all.extend(list.workers);
            match list.next {
                Some(next) => after = Some(next),
                None => break,
            }
        }
        Ok(WorkerList {
            total: all.len() as u64,
            per_page: all.len().max(1).try_into().unwrap_or(u32::MAX),
            workers: all,
            page: 1,
            next: None,
        })
    }
}
